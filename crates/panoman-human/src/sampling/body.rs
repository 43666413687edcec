//! Body poses: spine and head, arms, legs (docs/design/rig-and-ik.md §3.1).

use super::*;

/// Leg modes of [`BodyPoseSampler`] and their probabilities.
pub const LEG_MODES: [(&str, f64); 4] = [
    ("stand", 0.40),
    ("walk", 0.30),
    ("sit", 0.15),
    ("raise", 0.15),
];

/// Correlated body poses (docs/design/rig-and-ik.md §3.2 body bones, docs/design/rig-and-ik.md §3.3 ranges); hands relaxed (mild grip), face at
/// rest. Left-side convention, right side mirrored (module docs). All draws are clamped to
/// [`bone_range`] at the end.
///
/// * **Spine** (5 bones): total flexion `F ~ TN(8, 15; −36, 56)` (the sum of the per-bone
///   ranges, inside docs/design/rig-and-ik.md §3.3's −40..60), split 22/22/22/17/17 % from spine05 (lowest) up, plus
///   `N(0, 1.5)` per bone; lateral bend `TN(0, 6; −20, 20)` and twist `TN(0, 8; −25, 25)`
///   split evenly, plus `N(0, 1)`.
/// * **Neck + head**: pitch `TN(0, 12; −35, 45)`, yaw `TN(0, 20; −50, 50)`, roll
///   `TN(0, 6; −20, 20)`, 18 / 18 / 18 / 46 % (pitch), 20 / 20 / 20 / 40 % (yaw, roll) over
///   neck01–03 and head, plus `N(0, 1)`.
/// * **Arms** (each side): with p = 0.35 *relaxed* — upperarm01 abduction (z)
///   `TN(−25, 10; −40, 10)`, flexion (x) `TN(5, 12; −30, 40)`, elbow `TN(15, 20; −35, 70)`;
///   else *free* — abduction `U(−40, 90)`, flexion `U(−40, 90)`, elbow `U(−35, 95)`. With
///   p = 0.3 the right arm copies the left draw plus `N(0, 6)` (symmetric tendency).
///   upperarm01 twist `TN(0, 15; ±45)`; elbow y `TN(0, 5; ±20)`. Shoulder girdle follows the
///   arm (scapulohumeral rhythm): clavicle z = 0.12·max(abd, 0) + N(0, 3), x = 0.08·flex +
///   N(0, 3), y ~ N(0, 2); shoulder01 z = 0.08·max(abd, 0) + N(0, 2.5), x = 0.05·flex +
///   N(0, 2.5), y ~ N(0, 2). Wrist deviation `TN(0, 7; ±20)`, twist `TN(0, 4; ±10)`,
///   flexion `TN(−5, 18; −60, 50)`.
/// * **Legs**: a mode from [`LEG_MODES`]: *stand* — hip flexion (x) `TN(−4, 7; −25, 15)`,
///   knee `TN(5, 7; 0, 30)` per leg; *walk* — phase `φ ~ U(0, 2π)`, amplitude
///   `a ~ U(10, 35)`, hip x = −a·sin φ (right leg φ + π), knee = 5 + 1.6·a·max(0, sin(φ +
///   0.9)) + N(0, 4), ankle x = 0.3·a·sin φ; *sit* — shared hip flexion `U(−90, −45)` and knee
///   `U(45, 120)` with `N(0, 6)` asymmetry; *raise* — one random leg with hip `U(−90, −20)`,
///   knee `U(0, 120)`, the other standing. Every leg then adds hip abduction (z)
///   `TN(−4, 8; −35, 15)` (−z = abduction on L), hip twist `TN(0, 8; ±30)`, knee y
///   `TN(0, 3; ±8)`, foot x `+TN(0, 6; −20, 40)`, foot y `TN(0, 3; ±10)`, foot z
///   `TN(0, 5; ±15)`.
/// * **`*02` twists**: `TN(0, L/2; ±L)` with `L` from [`TWIST_LIMIT_DEG`].
/// * **Hands**: [`HandSampler::relaxed_into`] per hand.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BodyPoseSampler;

impl BodyPoseSampler {
    /// Draws one body pose (see the type docs).
    pub fn sample(&self, rng: &mut impl RngCore) -> Theta {
        let mut th = Theta::default();
        sample_spine_and_head(rng, &mut th);
        sample_arms(rng, &mut th);
        sample_legs(rng, &mut th);

        // Hands relaxed.
        let hands = HandSampler;
        for right in [false, true] {
            hands.relaxed_into(rng, &mut th, right);
        }
        th.clamp_to_ranges();
        th
    }
}

/// The spine, neck and head part of [`BodyPoseSampler::sample`].
pub(super) fn sample_spine_and_head(rng: &mut dyn RngCore, th: &mut Theta) {
    let tn = |rng: &mut dyn RngCore, m: f64, s: f64, lo: f64, hi: f64| {
        truncated_normal(rng, m, s, lo, hi)
    };
    let n = |rng: &mut dyn RngCore, s: f64| s * normal(rng);
    // Spine.
    let flex = tn(rng, 8.0, 15.0, -36.0, 56.0);
    let bend = tn(rng, 0.0, 6.0, -20.0, 20.0);
    let twist = tn(rng, 0.0, 8.0, -25.0, 25.0);
    let shares = [0.22, 0.22, 0.22, 0.17, 0.17];
    for (b, share) in shares.iter().enumerate() {
        th.deg[b] = [
            flex * share + n(rng, 1.5),
            twist / 5.0 + n(rng, 1.0),
            bend / 5.0 + n(rng, 1.0),
        ];
    }
    // Neck and head.
    let pitch = tn(rng, 0.0, 12.0, -35.0, 45.0);
    let yaw = tn(rng, 0.0, 20.0, -50.0, 50.0);
    let roll = tn(rng, 0.0, 6.0, -20.0, 20.0);
    for (k, (sp, sr)) in [(0.18, 0.2), (0.18, 0.2), (0.18, 0.2), (0.46, 0.4)]
        .iter()
        .enumerate()
    {
        th.deg[5 + k] = [
            pitch * sp + n(rng, 1.0),
            yaw * sr + n(rng, 1.0),
            roll * sr + n(rng, 1.0),
        ];
    }
}

/// The arms of [`BodyPoseSampler::sample`] (clavicles to wrists, both sides).
pub(super) fn sample_arms(rng: &mut dyn RngCore, th: &mut Theta) {
    let tn = |rng: &mut dyn RngCore, m: f64, s: f64, lo: f64, hi: f64| {
        truncated_normal(rng, m, s, lo, hi)
    };
    let n = |rng: &mut dyn RngCore, s: f64| s * normal(rng);
    // Arms: (abduction z, flexion x, elbow x) per side, left convention.
    let draw_arm = |rng: &mut dyn RngCore| -> [f64; 3] {
        if uniform(rng) < 0.35 {
            [
                truncated_normal(rng, -25.0, 10.0, -40.0, 10.0),
                truncated_normal(rng, 5.0, 12.0, -30.0, 40.0),
                truncated_normal(rng, 15.0, 20.0, -35.0, 70.0),
            ]
        } else {
            [
                uniform_in(rng, -40.0, 90.0),
                uniform_in(rng, -40.0, 90.0),
                uniform_in(rng, -35.0, 95.0),
            ]
        }
    };
    let left_arm = draw_arm(rng);
    let right_arm = if uniform(rng) < 0.3 {
        left_arm.map(|v| v + 6.0 * normal(rng))
    } else {
        draw_arm(rng)
    };
    for (side, arm) in [(false, left_arm), (true, right_arm)] {
        let s = usize::from(side);
        let [abd, flx, elbow] = arm;
        let abd = abd.clamp(-40.0, 90.0);
        let flx = flx.clamp(-40.0, 90.0);
        let clav = [
            0.08 * flx + n(rng, 3.0),
            n(rng, 2.0),
            0.12 * abd.max(0.0) + n(rng, 3.0),
        ];
        th.set_lr(slot("clavicle.L") + s, side, clav);
        let sh = [
            0.05 * flx + n(rng, 2.5),
            n(rng, 2.0),
            0.08 * abd.max(0.0) + n(rng, 2.5),
        ];
        th.set_lr(slot("shoulder01.L") + s, side, sh);
        let ua = [flx, tn(rng, 0.0, 15.0, -45.0, 45.0), abd];
        th.set_lr(slot("upperarm01.L") + s, side, ua);
        let la = [elbow, tn(rng, 0.0, 5.0, -20.0, 20.0), 0.0];
        th.set_lr(slot("lowerarm01.L") + s, side, la);
        for bone in ["upperarm02", "lowerarm02"] {
            let l = twist_limit(bone);
            let t = tn(rng, 0.0, l / 2.0, -l, l);
            th.set_lr(slot(&format!("{bone}.L")) + s, side, [0.0, t, 0.0]);
        }
        let wr = [
            tn(rng, 0.0, 7.0, -20.0, 20.0),
            tn(rng, 0.0, 4.0, -10.0, 10.0),
            tn(rng, -5.0, 18.0, -60.0, 50.0),
        ];
        th.set_lr(slot("wrist.L") + s, side, wr);
    }
}

/// The legs of [`BodyPoseSampler::sample`] (a leg mode, then hips to feet, both sides).
pub(super) fn sample_legs(rng: &mut dyn RngCore, th: &mut Theta) {
    let tn = |rng: &mut dyn RngCore, m: f64, s: f64, lo: f64, hi: f64| {
        truncated_normal(rng, m, s, lo, hi)
    };
    let n = |rng: &mut dyn RngCore, s: f64| s * normal(rng);
    // Legs: (hip flexion x, knee x, foot x) per side.
    let mode = choose_weighted(rng, &LEG_MODES.map(|(_, p)| p));
    let stand = |rng: &mut dyn RngCore| -> [f64; 3] {
        [
            truncated_normal(rng, -4.0, 7.0, -25.0, 15.0),
            truncated_normal(rng, 5.0, 7.0, 0.0, 30.0),
            0.0,
        ]
    };
    let legs: [[f64; 3]; 2] = match LEG_MODES[mode].0 {
        "stand" => [stand(rng), stand(rng)],
        "walk" => {
            let phi = uniform_in(rng, 0.0, std::f64::consts::TAU);
            let a = uniform_in(rng, 10.0, 35.0);
            let mut leg = |ph: f64| {
                let knee = 5.0 + 1.6 * a * (ph + 0.9).sin().max(0.0) + n(rng, 4.0);
                [-a * ph.sin(), knee, 0.3 * a * ph.sin()]
            };
            [leg(phi), leg(phi + std::f64::consts::PI)]
        }
        "sit" => {
            let hip = uniform_in(rng, -90.0, -45.0);
            let knee = uniform_in(rng, 45.0, 120.0);
            let mut leg = || [hip + n(rng, 6.0), knee + n(rng, 6.0), n(rng, 5.0)];
            [leg(), leg()]
        }
        _ => {
            let raised = [
                uniform_in(rng, -90.0, -20.0),
                uniform_in(rng, 0.0, 120.0),
                n(rng, 8.0),
            ];
            let other = stand(rng);
            if uniform(rng) < 0.5 {
                [raised, other]
            } else {
                [other, raised]
            }
        }
    };
    for (side, leg) in [(false, legs[0]), (true, legs[1])] {
        let s = usize::from(side);
        let [hip, knee, foot] = leg;
        let ul = [
            hip,
            tn(rng, 0.0, 8.0, -30.0, 30.0),
            tn(rng, -4.0, 8.0, -35.0, 15.0),
        ];
        th.set_lr(slot("upperleg01.L") + s, side, ul);
        let ll = [knee, tn(rng, 0.0, 3.0, -8.0, 8.0), 0.0];
        th.set_lr(slot("lowerleg01.L") + s, side, ll);
        for bone in ["upperleg02", "lowerleg02"] {
            let l = twist_limit(bone);
            let t = tn(rng, 0.0, l / 2.0, -l, l);
            th.set_lr(slot(&format!("{bone}.L")) + s, side, [0.0, t, 0.0]);
        }
        let ft = [
            foot + tn(rng, 0.0, 6.0, -20.0, 40.0),
            tn(rng, 0.0, 3.0, -10.0, 10.0),
            tn(rng, 0.0, 5.0, -15.0, 15.0),
        ];
        th.set_lr(slot("foot.L") + s, side, ft);
    }
}
