//! Throughput of the MLP toolkit (docs/design/splocs-model.md §5) on synthetic data:
//! `cargo run --release -p panoman-model --example mlp_bench [-- epochs N pca_n pca_d]`.
//!
//! * correction MLP 500 → 1500 → 256 (PCA head codes), N samples, batch 128, MSE;
//! * motion MLP 138 → 400 → 600 → 500, N samples, batch 128, MSE and Gram-metric loss;
//! * single-sample forward and Jacobian latency;
//! * PCA head fit on an `pca_n × pca_d` target matrix (r ≤ 256, 2 power iterations).

use std::ops::ControlFlow;
use std::time::Instant;

use faer::Mat;
use panoman_model::mlp::{
    EpochStats, Loss, Mlp, MlpDataset, MlpTrainConfig, OutputNorm, PcaHead, PcaHeadOptions, train,
};

struct Gen(u64);
impl Gen {
    fn normal(&mut self) -> f32 {
        let mut u = || {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        };
        let (u1, u2) = (1.0 - u(), u());
        ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
    }
}

/// Inputs N(0, 1) and targets from a random ReLU teacher network.
fn teacher_data(n: usize, din: usize, dout: usize, seed: u64) -> (Mat<f32>, Mat<f32>) {
    let mut g = Gen(seed);
    let x = Mat::<f32>::from_fn(n, din, |_, _| g.normal());
    let teacher = Mlp::new(&[din, 64, dout], seed).unwrap();
    let y = teacher.forward(x.as_ref()).unwrap();
    (x, y)
}

fn bench_training(name: &str, sizes: &[usize], n: usize, epochs: usize, loss: Loss) {
    let (din, dout) = (sizes[0], sizes[sizes.len() - 1]);
    let (x, y) = teacher_data(n, din, dout, 3);
    let data = MlpDataset::new(x.as_ref(), y.as_ref()).unwrap();
    let nval = n / 10;
    let (xv, yv) = teacher_data(nval, din, dout, 4);
    let val = MlpDataset::new(xv.as_ref(), yv.as_ref()).unwrap();
    let mut model = Mlp::new(sizes, 1).unwrap();
    let cfg = MlpTrainConfig {
        epochs,
        loss,
        output_norm: OutputNorm::Global,
        ..MlpTrainConfig::default()
    };
    let mut last = 0.0;
    let mut per_epoch = Vec::new();
    let report = train(
        &mut model,
        &data,
        Some(&val),
        &cfg,
        &mut |s: &EpochStats| {
            per_epoch.push(s.seconds - last);
            last = s.seconds;
            println!(
                "  {name} epoch {:3}: train {:.4e} val {:.4e} ({:.3} s)",
                s.epoch,
                s.train_loss,
                s.val_loss.unwrap_or(f64::NAN),
                per_epoch[per_epoch.len() - 1]
            );
            ControlFlow::Continue(())
        },
    )
    .unwrap();
    let steps_per_epoch = n.div_ceil(128);
    let mut sorted = per_epoch.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    println!(
        "{name}: {} params, N = {n}, {} steps/epoch: median {:.3} s/epoch (incl. validation on {nval}), {:.1} steps/s, total {:.2} s",
        model.parameters().len(),
        steps_per_epoch,
        median,
        steps_per_epoch as f64 / median,
        report.seconds
    );
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let epochs = args.first().copied().unwrap_or(5);
    let n = args.get(1).copied().unwrap_or(4000);
    let pca_n = args.get(2).copied().unwrap_or(2000);
    let pca_d = args.get(3).copied().unwrap_or(75_000);
    println!("rayon threads: {}", rayon::current_num_threads());

    bench_training(
        "correction 500-1500-256 MSE",
        &[500, 1500, 256],
        n,
        epochs,
        Loss::Mse,
    );
    bench_training(
        "motion 138-400-600-500 MSE",
        &[138, 400, 600, 500],
        n,
        epochs,
        Loss::Mse,
    );
    let mut g = Gen(9);
    let a = Mat::<f32>::from_fn(500, 500, |_, _| g.normal());
    let gram = Mat::<f64>::from_fn(500, 500, |i, j| {
        (0..500)
            .map(|k| f64::from(a[(i, k)]) * f64::from(a[(j, k)]))
            .sum::<f64>()
            / 500.0
            + if i == j { 0.1 } else { 0.0 }
    });
    bench_training(
        "motion 138-400-600-500 metric",
        &[138, 400, 600, 500],
        n,
        epochs,
        Loss::Metric(gram),
    );

    let model = Mlp::new(&[500, 1500, 256], 2).unwrap();
    let x: Vec<f32> = (0..500).map(|_| g.normal()).collect();
    let reps = 2000;
    let t = Instant::now();
    let mut acc = 0.0f32;
    for _ in 0..reps {
        acc += model.forward_one(&x)[0];
    }
    let fwd = t.elapsed().as_secs_f64() / reps as f64;
    let t = Instant::now();
    for _ in 0..200 {
        let (_, j) = model.jacobian(&x);
        acc += j.factors()[0][(0, 0)];
    }
    let jac = t.elapsed().as_secs_f64() / 200.0;
    let t = Instant::now();
    for _ in 0..200 {
        acc += model.jacobian_dense(&x).1[(0, 0)];
    }
    let jd = t.elapsed().as_secs_f64() / 200.0;
    println!(
        "correction MLP single sample: forward_one {:.1} µs, factored Jacobian {:.1} µs, dense 256×500 Jacobian {:.1} µs ({acc:.1})",
        fwd * 1e6,
        jac * 1e6,
        jd * 1e6
    );

    if pca_n > 0 && pca_d > 0 {
        // Targets with a decaying spectrum of 300 components plus noise.
        let rank = 300;
        let u = Mat::<f32>::from_fn(pca_n, rank, |_, k| g.normal() * 0.985f32.powi(k as i32));
        let v = Mat::<f32>::from_fn(rank, pca_d, |_, _| g.normal());
        let mut y = &u * &v;
        for j in 0..pca_d {
            for i in 0..pca_n {
                y[(i, j)] += 0.05 * g.normal();
            }
        }
        let t = Instant::now();
        let fit = PcaHead::fit(
            y.as_ref(),
            None,
            &PcaHeadOptions {
                max_rank: 256,
                target_explained: 0.99,
                ..Default::default()
            },
        )
        .unwrap();
        println!(
            "PCA head {pca_n}×{pca_d}: rank {}, explained {:.4}, {:.2} s",
            fit.head.rank(),
            fit.explained_ratio,
            t.elapsed().as_secs_f64()
        );
    }
}
