//! Avatars as other tools make them, written by `glb_write::write_meshes` and read back by the
//! loader: viseme and ARKit targets side by side, several primitives and materials per mesh,
//! teeth meshes with targets of their own, teeth skinned to a jaw joint without any, and
//! single- and double-sided materials.

mod common;

use common::glb_write::{MeshOut, PrimitiveOut, write_meshes};
use glam::Vec3;
use lipcall::render::HeadModel;
use lipcall::render::arkit;
use lipcall::render::gltf_load::load_head_from_slice;
use lipcall::render::head::{Material, MorphDelta, TargetSource, Vertex};
use lipcall::render::offscreen::{FrameOptions, OffscreenRenderer};
use lipcall::vocab::VisemeWeights;

fn v(name: &str) -> usize {
    lipcall::vocab::Viseme::from_name(name).unwrap().index()
}

/// An `n` x `n` grid over the rectangle at depth `z`, facing +Z.
fn grid(rect: [f32; 4], z: f32, n: usize, material: usize) -> PrimitiveOut {
    let (vertices, indices) = common::mesh::grid(rect, z, n);
    PrimitiveOut {
        vertices,
        indices,
        material,
        ..Default::default()
    }
}

/// Every vertex of `p` moved by `f(position)`.
fn shape(p: &PrimitiveOut, f: impl Fn(Vec3) -> Vec3) -> Vec<MorphDelta> {
    common::mesh::deltas(&p.vertices, f)
}

/// Moves the lower half (y < 0) by `d`.
fn lower_half(p: &PrimitiveOut, d: Vec3) -> Vec<MorphDelta> {
    shape(p, |q| if q.y < 0.0 { d } else { Vec3::ZERO })
}

fn material(name: &str, base_color: [f32; 4]) -> Material {
    Material {
        name: name.into(),
        base_color,
        ..Material::default()
    }
}

/// Makes a target's deltas for a primitive.
type Deltas<'a> = &'a dyn Fn(&PrimitiveOut) -> Vec<MorphDelta>;

/// A mesh whose primitives carry `targets` (name, delta maker) each.
fn mesh(name: &str, mut primitives: Vec<PrimitiveOut>, targets: &[(&str, Deltas)]) -> MeshOut {
    for p in &mut primitives {
        p.targets = targets.iter().map(|(_, f)| f(p)).collect();
    }
    MeshOut {
        name: name.into(),
        primitives,
        target_names: targets.iter().map(|(n, _)| n.to_string()).collect(),
        joint_names: Vec::new(),
    }
}

fn load(meshes: &[MeshOut]) -> HeadModel {
    let materials = [
        material("skin", [0.8, 0.55, 0.45, 1.0]),
        material("teeth", [0.9, 0.9, 0.85, 1.0]),
    ];
    load_head_from_slice(&write_meshes(meshes, &materials)).expect("the avatar loads")
}

/// The index of the (first) primitive of the named mesh.
fn prim(head: &HeadModel, name: &str) -> usize {
    head.primitives.iter().position(|p| p.name == name).unwrap()
}

/// The position delta of `slot` at vertex `i` of the named mesh's primitive (zero where the
/// slot is empty).
fn delta(head: &HeadModel, mesh: &str, slot: usize, i: usize) -> Vec3 {
    head.primitives[prim(head, mesh)].targets[slot]
        .get(i)
        .map_or(Vec3::ZERO, |d| Vec3::from(d.position))
}

fn recipe_weight(viseme: &str, shape: &str) -> f32 {
    arkit::matrix()[v(viseme)][arkit::arkit_index(shape).unwrap()]
}

#[test]
fn an_avatar_with_visemes_and_arkit_shapes_uses_its_visemes_and_arkit_fills_the_rest() {
    // Ready Player Me style: viseme_* and ARKit shapes on one mesh. viseme_aa moves the chin
    // 1 cm down, jawOpen 5 cm: aa must be the avatar's own 1 cm; E, which the avatar lacks, comes
    // from jawOpen through the recipe.
    let face = mesh(
        "Wolf3D_Head",
        vec![grid([-0.1, 0.1, -0.1, 0.1], 0.0, 9, 0)],
        &[
            ("viseme_sil", &|p| shape(p, |_| Vec3::ZERO)),
            ("viseme_aa", &|p| lower_half(p, Vec3::new(0.0, -0.01, 0.0))),
            ("viseme_PP", &|p| lower_half(p, Vec3::new(0.0, 0.002, 0.0))),
            ("jawOpen", &|p| lower_half(p, Vec3::new(0.0, -0.05, 0.0))),
        ],
    );
    let head = load(&[face]);
    assert_eq!(head.source, TargetSource::Visemes);
    assert!(
        head.missing_visemes.is_empty(),
        "{:?}",
        head.missing_visemes
    );
    let chin = 0; // vertex 0 is the bottom-left corner
    assert!(
        (delta(&head, "Wolf3D_Head", v("aa"), chin) - Vec3::new(0.0, -0.01, 0.0)).length() < 1e-6
    );
    assert!(
        (delta(&head, "Wolf3D_Head", v("PP"), chin) - Vec3::new(0.0, 0.002, 0.0)).length() < 1e-6
    );
    let e = -0.05 * recipe_weight("E", "jawOpen");
    assert!(e < 0.0);
    assert!((delta(&head, "Wolf3D_Head", v("E"), chin) - Vec3::new(0.0, e, 0.0)).length() < 1e-6);
    // sil stays the neutral face.
    assert_eq!(delta(&head, "Wolf3D_Head", v("sil"), chin), Vec3::ZERO);
}

#[test]
fn teeth_meshes_with_targets_of_their_own_move_by_the_same_rules() {
    let face = mesh(
        "Wolf3D_Head",
        vec![grid([-0.1, 0.1, -0.1, 0.1], 0.0, 9, 0)],
        &[
            ("viseme_aa", &|p| lower_half(p, Vec3::new(0.0, -0.01, 0.0))),
            ("jawOpen", &|p| lower_half(p, Vec3::new(0.0, -0.05, 0.0))),
        ],
    );
    // Ready Player Me's Wolf3D_Teeth: the same target names as the face.
    let teeth = mesh(
        "Wolf3D_Teeth",
        vec![grid([-0.03, 0.03, -0.05, -0.04], -0.01, 3, 1)],
        &[
            ("viseme_aa", &|p| shape(p, |_| Vec3::new(0.0, -0.008, 0.0))),
            ("jawOpen", &|p| shape(p, |_| Vec3::new(0.0, -0.04, 0.0))),
        ],
    );
    // Lower teeth that carry only jawOpen beside a viseme-named face take the recipe.
    let lower_teeth = mesh(
        "teethLower",
        vec![grid([-0.03, 0.03, -0.06, -0.05], -0.01, 3, 1)],
        &[("jawOpen", &|p| shape(p, |_| Vec3::new(0.0, -0.04, 0.0)))],
    );
    let head = load(&[face, teeth, lower_teeth]);
    assert_eq!(head.source, TargetSource::Visemes);
    assert_eq!(head.primitives.len(), 3);
    assert!(
        (delta(&head, "Wolf3D_Teeth", v("aa"), 0) - Vec3::new(0.0, -0.008, 0.0)).length() < 1e-6
    );
    let aa = -0.04 * recipe_weight("aa", "jawOpen");
    assert!((delta(&head, "teethLower", v("aa"), 0) - Vec3::new(0.0, aa, 0.0)).length() < 1e-6);
    let o = -0.04 * recipe_weight("O", "jawOpen");
    assert!((delta(&head, "teethLower", v("O"), 0) - Vec3::new(0.0, o, 0.0)).length() < 1e-6);
    // An ARKit-only avatar's teeth follow jawOpen through the recipe as well.
    let face = mesh(
        "head",
        vec![grid([-0.1, 0.1, -0.1, 0.1], 0.0, 9, 0)],
        &[("jawOpen", &|p| lower_half(p, Vec3::new(0.0, -0.05, 0.0)))],
    );
    let teeth = mesh(
        "teeth",
        vec![grid([-0.03, 0.03, -0.06, -0.05], -0.01, 3, 1)],
        &[("jawOpen", &|p| shape(p, |_| Vec3::new(0.0, -0.04, 0.0)))],
    );
    let head = load(&[face, teeth]);
    assert_eq!(head.source, TargetSource::Arkit);
    assert!((delta(&head, "teeth", v("aa"), 0) - Vec3::new(0.0, aa, 0.0)).length() < 1e-6);
}

#[test]
fn teeth_skinned_to_a_jaw_joint_without_targets_follow_the_jaw() {
    // The face opens 2 cm at the chin for aa, 1 cm for E, and only pushes the lips forward for U.
    let face = mesh(
        "head",
        vec![grid([-0.1, 0.1, -0.1, 0.1], 0.0, 9, 0)],
        &[
            ("viseme_aa", &|p| lower_half(p, Vec3::new(0.0, -0.02, 0.0))),
            ("viseme_E", &|p| lower_half(p, Vec3::new(0.0, -0.01, 0.0))),
            ("viseme_U", &|p| lower_half(p, Vec3::new(0.0, 0.0, 0.01))),
        ],
    );
    let skinned = |name: &str, joints: &[&str], y: f32| {
        let mut p = grid([-0.03, 0.03, y, y + 0.01], -0.01, 3, 1);
        // Half the vertices wholly on the first joint, the rest half on each.
        p.joints = (0..p.vertices.len())
            .map(|i| {
                if i % 2 == 0 {
                    [(0, 1.0), (0, 0.0), (0, 0.0), (0, 0.0)]
                } else {
                    [(0, 0.5), (1, 0.5), (0, 0.0), (0, 0.0)]
                }
            })
            .collect();
        MeshOut {
            name: name.into(),
            primitives: vec![p],
            target_names: Vec::new(),
            joint_names: joints.iter().map(|j| j.to_string()).collect(),
        }
    };
    let head = load(&[
        face,
        skinned("Wolf3D_Teeth", &["Jaw", "Head"], -0.06),
        skinned("upper teeth", &["Head", "Neck"], -0.03),
    ]);
    // Lower teeth: the whole jaw opening where wholly on the jaw, half where half.
    assert!(
        (delta(&head, "Wolf3D_Teeth", v("aa"), 0) - Vec3::new(0.0, -0.02, 0.0)).length() < 1e-5
    );
    assert!(
        (delta(&head, "Wolf3D_Teeth", v("aa"), 1) - Vec3::new(0.0, -0.01, 0.0)).length() < 1e-5
    );
    assert!((delta(&head, "Wolf3D_Teeth", v("E"), 0) - Vec3::new(0.0, -0.01, 0.0)).length() < 1e-5);
    // Rounding moves the lips forward, not the jaw down: the teeth stay.
    assert_eq!(delta(&head, "Wolf3D_Teeth", v("U"), 0), Vec3::ZERO);
    // Teeth skinned to no jaw joint keep their bind pose.
    assert!(!head.primitives[prim(&head, "upper teeth")].has_targets());
}

#[test]
fn each_primitive_of_a_mesh_is_drawn_with_its_own_material() {
    // One mesh, two primitives: the left half red, the right half blue.
    let face = mesh(
        "face",
        vec![
            grid([-0.1, 0.0, -0.1, 0.1], 0.0, 5, 0),
            grid([0.0, 0.1, -0.1, 0.1], 0.0, 5, 1),
        ],
        &[("jawOpen", &|p| lower_half(p, Vec3::new(0.0, -0.01, 0.0)))],
    );
    let materials = [
        material("red", [0.8, 0.05, 0.05, 1.0]),
        material("blue", [0.05, 0.05, 0.8, 1.0]),
    ];
    let head = load_head_from_slice(&write_meshes(&[face], &materials)).unwrap();
    assert_eq!(head.primitives.len(), 2);
    assert_ne!(head.primitives[0].material, head.primitives[1].material);
    let Some(ctx) = common::gpu() else { return };
    let options = FrameOptions {
        width: 64,
        height: 64,
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(&ctx, &head, options).unwrap();
    let img = offscreen.render(&ctx, &VisemeWeights::neutral()).unwrap();
    let count = |left: bool, red: bool| {
        img.enumerate_pixels()
            .filter(|(x, _, _)| (*x < 32) == left)
            .filter(|(_, _, p)| {
                let (r, b) = (p[0] as i32, p[2] as i32);
                if red { r > b + 60 } else { b > r + 60 }
            })
            .count()
    };
    // The head itself is the picture's own left (+X) on screen's right: whichever side each
    // colour lands on, each half is one colour only.
    let (red_left, red_right) = (count(true, true), count(false, true));
    let (blue_left, blue_right) = (count(true, false), count(false, false));
    assert!(
        (red_left > 200 && blue_right > 200 && red_right < 20 && blue_left < 20)
            || (red_right > 200 && blue_left > 200 && red_left < 20 && blue_right < 20),
        "red {red_left}/{red_right}, blue {blue_left}/{blue_right} (left/right)"
    );
}

#[test]
fn back_faces_are_drawn_only_for_double_sided_materials() {
    // A card turned away from the camera (its triangles wound the other way), once with a
    // single-sided material and once double-sided; a card facing the camera beside it shows
    // that the frame was drawn at all.
    let away = |p: PrimitiveOut| PrimitiveOut {
        indices: p
            .indices
            .chunks(3)
            .flat_map(|t| [t[0], t[2], t[1]])
            .collect(),
        vertices: p
            .vertices
            .iter()
            .map(|v| Vertex {
                normal: [0.0, 0.0, -1.0],
                ..*v
            })
            .collect(),
        ..p
    };
    let Some(ctx) = common::gpu() else { return };
    let red_pixels = |double_sided: bool| {
        let face = mesh(
            "face",
            vec![
                grid([-0.1, 0.0, -0.1, 0.1], 0.0, 5, 0),
                away(grid([0.0, 0.1, -0.1, 0.1], 0.0, 5, 1)),
            ],
            &[("jawOpen", &|p| lower_half(p, Vec3::new(0.0, -0.01, 0.0)))],
        );
        let materials = [
            material("blue", [0.05, 0.05, 0.8, 1.0]),
            Material {
                double_sided,
                ..material("red", [0.8, 0.05, 0.05, 1.0])
            },
        ];
        let head = load_head_from_slice(&write_meshes(&[face], &materials)).unwrap();
        assert_eq!(head.materials[1].double_sided, double_sided);
        let options = FrameOptions {
            width: 64,
            height: 64,
            ..Default::default()
        };
        let mut offscreen = OffscreenRenderer::new(&ctx, &head, options).unwrap();
        let img = offscreen.render(&ctx, &VisemeWeights::neutral()).unwrap();
        let count = |red: bool| {
            img.pixels()
                .filter(|p| {
                    let (r, b) = (p[0] as i32, p[2] as i32);
                    if red { r > b + 60 } else { b > r + 60 }
                })
                .count()
        };
        assert!(count(false) > 200, "the facing card is drawn");
        count(true)
    };
    assert_eq!(
        red_pixels(false),
        0,
        "a single-sided card seen from behind is culled"
    );
    assert!(
        red_pixels(true) > 200,
        "a double-sided card is drawn from behind"
    );
}
