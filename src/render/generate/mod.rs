//! The default head, built procedurally: skin (a ray-cast implicit surface with a split along the
//! lip line), inner lips, mouth cavity, teeth, tongue and eyes, plus one morph target per viseme
//! made by deforming the whole head into each viseme's [`pose::MouthPose`].
//!
//! `cargo run --release --example build_head` writes it to `assets/heads/default.glb`.

pub mod pose;

use glam::{Vec2, Vec3};

use super::head::{
    HeadModel, Material, MorphDelta, Primitive, TargetSource, VISEME_COUNT, Vertex, smooth_normals,
};
use pose::{Anatomy, MouthPose, Part, deform, viseme_poses};

/// sRGB colour to linear RGBA.
fn srgb(r: f32, g: f32, b: f32) -> [f32; 4] {
    let f = |c: f32| c.powf(2.2);
    [f(r), f(g), f(b), 1.0]
}

fn mix4(a: [f32; 4], b: [f32; 4], t: f32) -> [f32; 4] {
    let t = t.clamp(0.0, 1.0);
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
        1.0,
    ]
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Polynomial smooth minimum (union of distance fields).
fn smin(a: f32, b: f32, k: f32) -> f32 {
    let h = (0.5 + 0.5 * (b - a) / k).clamp(0.0, 1.0);
    b + (a - b) * h - k * h * (1.0 - h)
}

/// Approximate signed distance to an axis-aligned ellipsoid.
fn ellipsoid(p: Vec3, c: Vec3, r: Vec3) -> f32 {
    let q = (p - c) / r;
    (q.length() - 1.0) * r.min_element()
}

/// Gaussian bump.
fn bump(d2: f32) -> f32 {
    (-d2).exp()
}

/// The head's implicit surface (negative inside), without the mouth details that the
/// pose deformation adds.
struct HeadShape {
    mouth_y: f32,
    half_width: f32,
}

impl HeadShape {
    fn field(&self, p: Vec3) -> f32 {
        let ax = p.x.abs();
        // Cranium.
        let cranium = ellipsoid(
            p,
            Vec3::new(0.0, 0.042, -0.014),
            Vec3::new(0.0755, 0.1, 0.102),
        );
        // Lower face and jaw, narrowing to the chin.
        let taper = 1.0 - 0.33 * smoothstep(0.0, -0.09, p.y);
        let jaw = ellipsoid(
            Vec3::new(p.x / taper, p.y, p.z),
            Vec3::new(0.0, -0.028, 0.01),
            Vec3::new(0.066, 0.062, 0.086),
        );
        let mut f = smin(cranium, jaw, 0.02);
        // Chin.
        f = smin(
            f,
            ellipsoid(
                p,
                Vec3::new(0.0, -0.072, 0.07),
                Vec3::new(0.022, 0.016, 0.02),
            ),
            0.012,
        );
        // Neck, slanting slightly forward.
        let neck_c = Vec2::new(p.x, p.z - (-0.018 + 0.1 * (p.y + 0.1)));
        let neck = (neck_c / Vec2::new(0.047, 0.045)).length() * 0.045 - 0.045;
        let neck = neck.max(-(p.y + 0.2)).max(p.y + 0.01);
        f = smin(f, neck, 0.025);
        // Ears.
        let ear = ellipsoid(
            Vec3::new(ax, p.y, p.z),
            Vec3::new(0.071, 0.017, -0.008),
            Vec3::new(0.013, 0.031, 0.017),
        );
        f = smin(f, ear, 0.006);

        let front = smoothstep(0.02, 0.07, p.z);
        let mut bumps = 0.0;
        // Nose: a ridge from between the eyes to the tip, with wings at the base.
        let t = ((0.034 - p.y) / 0.046).clamp(0.0, 1.0);
        let nose_h = 0.004 + 0.0165 * t.powf(1.2) * smoothstep(-0.02, -0.008, p.y);
        let nose_w = 0.008 + 0.007 * t;
        bumps += nose_h * bump((ax / nose_w).powi(2) * 1.2) * smoothstep(0.045, 0.03, p.y) * front;
        let wings = bump(((ax - 0.0135) / 0.0065).powi(2) + ((p.y + 0.006) / 0.0065).powi(2));
        bumps += 0.008 * wings * front;
        // Brow ridge and forehead.
        bumps +=
            0.006 * bump(((ax - 0.03) / 0.02).powi(2) + ((p.y - 0.05) / 0.008).powi(2)) * front;
        // Cheekbones.
        bumps +=
            0.006 * bump(((ax - 0.044) / 0.016).powi(2) + ((p.y - 0.008) / 0.014).powi(2)) * front;
        // Lips: upper with a cupid's bow, fuller lower lip, philtrum and chin fold.
        let dy = p.y - self.mouth_y;
        let lipx = (p.x / self.half_width).powi(2);
        let lip_span = (1.0 - lipx).max(0.0).sqrt();
        let bow = 0.0012 * bump((p.x / 0.004).powi(2));
        let upper = bump(((dy - 0.0045 + bow) / 0.0045).powi(2)) * lip_span;
        let lower = bump(((dy + 0.0055) / 0.005).powi(2)) * lip_span;
        bumps += (0.0032 * upper + 0.0045 * lower) * front;
        bumps += 0.0012
            * bump((ax / 0.0045).powi(2) + ((dy - 0.012) / 0.006).powi(2))
            * (1.0 - 2.0 * bump((ax / 0.002).powi(2)))
            * front;
        bumps -= 0.002 * bump((p.x / 0.014).powi(2) + ((dy + 0.019) / 0.004).powi(2)) * front;
        // Mouth corners sink a little.
        bumps -=
            0.003 * bump(((ax - self.half_width) / 0.004).powi(2) + (dy / 0.005).powi(2)) * front;
        // Hair volume on the cranium.
        bumps += 0.005 * hair_mask(p);
        f - bumps
    }

    /// Eye sockets are cut out of the field, leaving depressions the eyeballs sit in.
    fn field_with_sockets(&self, p: Vec3) -> f32 {
        let f = self.field(p);
        let socket = ellipsoid(
            Vec3::new(p.x.abs(), p.y, p.z),
            Vec3::new(EYE_X, EYE_Y + 0.0005, EYE_Z + 0.002),
            Vec3::new(0.0155, 0.0072, 0.013),
        );
        f.max(-socket)
    }

    /// Outermost surface point along the ray from the origin in direction `d`.
    fn cast(&self, d: Vec3) -> Vec3 {
        let mut outside = 0.4;
        let step = 0.004;
        let mut r = outside;
        while r > 0.0 {
            if self.field_with_sockets(d * r) < 0.0 {
                break;
            }
            outside = r;
            r -= step;
        }
        let mut inside = r.max(0.0);
        for _ in 0..30 {
            let mid = 0.5 * (inside + outside);
            if self.field_with_sockets(d * mid) < 0.0 {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        d * (0.5 * (inside + outside))
    }
}

const EYE_X: f32 = 0.0315;
const EYE_Y: f32 = 0.031;
const EYE_Z: f32 = 0.064;
const EYE_R: f32 = 0.0122;

fn hair_mask(p: Vec3) -> f32 {
    let azimuth = p.x.atan2(p.z).abs();
    let line = if azimuth < 1.0 {
        0.083 - 0.022 * smoothstep(0.25, 1.0, azimuth)
    } else {
        0.061 - 0.035 * smoothstep(1.0, 1.6, azimuth) - 0.07 * smoothstep(1.9, 2.9, azimuth)
    };
    smoothstep(line - 0.006, line + 0.008, p.y)
}

/// A part under construction: base positions, colours, how each vertex moves.
struct PartMesh {
    name: &'static str,
    material: usize,
    positions: Vec<Vec3>,
    colors: Vec<[f32; 4]>,
    parts: Vec<Part>,
    uvs: Vec<[f32; 2]>,
    /// Vertices that move exactly like another one (inner lips follow the lip edge).
    anchors: Vec<Option<u32>>,
    indices: Vec<u32>,
    morphs: bool,
}

impl PartMesh {
    fn new(name: &'static str, material: usize, morphs: bool) -> Self {
        Self {
            name,
            material,
            positions: Vec::new(),
            colors: Vec::new(),
            parts: Vec::new(),
            uvs: Vec::new(),
            anchors: Vec::new(),
            indices: Vec::new(),
            morphs,
        }
    }

    fn push(&mut self, p: Vec3, color: [f32; 4], part: Part, uv: [f32; 2]) -> u32 {
        self.positions.push(p);
        self.colors.push(color);
        self.parts.push(part);
        self.uvs.push(uv);
        self.anchors.push(None);
        (self.positions.len() - 1) as u32
    }

    /// Quad a-b-c-d (counter-clockwise seen from outside) as two triangles.
    fn quad(&mut self, a: u32, b: u32, c: u32, d: u32) {
        self.indices.extend_from_slice(&[a, b, c, a, c, d]);
    }

    /// Deforms the part into every viseme and stores positions + normal differences.
    fn finish(self, anatomy: &Anatomy, poses: &[MouthPose; VISEME_COUNT]) -> Primitive {
        let normals = smooth_normals(&self.positions, &self.indices);
        let vertices: Vec<Vertex> = (0..self.positions.len())
            .map(|i| Vertex {
                position: self.positions[i].into(),
                normal: normals[i].into(),
                uv: self.uvs[i],
                color: self.colors[i],
            })
            .collect();
        let mut prim = Primitive::new(self.name, self.material, vertices, self.indices.clone());
        if !self.morphs {
            return prim;
        }
        for (t, pose) in poses.iter().enumerate() {
            if *pose == MouthPose::default() {
                continue;
            }
            let mut moved: Vec<Vec3> = self
                .positions
                .iter()
                .zip(&self.parts)
                .map(|(&p, &part)| deform(p, part, pose, anatomy))
                .collect();
            for (i, anchor) in self.anchors.iter().enumerate() {
                if let Some(a) = anchor {
                    let a = *a as usize;
                    moved[i] = self.positions[i] + (moved[a] - self.positions[a]);
                }
            }
            let moved_normals = smooth_normals(&moved, &self.indices);
            let deltas: Vec<MorphDelta> = (0..moved.len())
                .map(|i| {
                    // Drop sub-micrometre noise so the GLB's sparse targets stay small.
                    let dp = moved[i] - self.positions[i];
                    let dn = moved_normals[i] - normals[i];
                    MorphDelta {
                        position: if dp.length() < 2e-6 {
                            [0.0; 3]
                        } else {
                            dp.into()
                        },
                        normal: if dn.length() < 1e-3 {
                            [0.0; 3]
                        } else {
                            dn.into()
                        },
                    }
                })
                .collect();
            if deltas.iter().any(|d| d.position != [0.0; 3]) {
                prim.targets[t] = deltas;
            }
        }
        prim
    }
}

/// Grid parameters: columns warp towards the front, rows towards the mouth line.
const COLUMNS: usize = 160;
const ROWS_ABOVE: usize = 84;
const ROWS_BELOW: usize = 56;

fn column_angle(i: usize) -> f32 {
    let u = -1.0 + 2.0 * i as f32 / COLUMNS as f32;
    std::f32::consts::PI * (0.4 * u + 0.6 * u * u * u)
}

fn direction(theta: f32, phi: f32) -> Vec3 {
    Vec3::new(theta.sin() * phi.cos(), phi.sin(), theta.cos() * phi.cos())
}

/// Builds the default head model.
pub fn build_default_head() -> HeadModel {
    let mouth_y = -0.036;
    let half_width = 0.0245;
    let shape = HeadShape {
        mouth_y,
        half_width,
    };
    // Elevation of the mouth line seen from the origin, found on the front meridian.
    let mut lo = -1.2f32;
    let mut hi = 0.3f32;
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if shape.cast(direction(0.0, mid)).y < mouth_y {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let phi_mouth = 0.5 * (lo + hi);
    let mouth_center = shape.cast(direction(0.0, phi_mouth));
    let mouth_z = mouth_center.z;
    let teeth_z = mouth_z - 0.0102;
    let anatomy = Anatomy {
        mouth_y,
        mouth_z,
        half_width,
        hinge: Vec3::new(0.0, -0.004, -0.002),
        teeth_z,
    };
    let poses = viseme_poses();

    let mut phis = Vec::new();
    let phi_top = 88.5f32.to_radians();
    let phi_bottom = -89.0f32.to_radians();
    for j in 0..ROWS_ABOVE {
        let t = 1.0 - j as f32 / ROWS_ABOVE as f32;
        phis.push(phi_mouth + (phi_top - phi_mouth) * t.powf(1.45));
    }
    let slit_row = phis.len();
    for j in 0..=ROWS_BELOW {
        let t = j as f32 / ROWS_BELOW as f32;
        phis.push(phi_mouth + (phi_bottom - phi_mouth) * t.powf(1.6));
    }

    let skin_color = srgb(0.86, 0.66, 0.55);
    let lip_color = srgb(0.70, 0.40, 0.39);
    let hair_color = srgb(0.22, 0.15, 0.11);
    let brow_color = srgb(0.25, 0.17, 0.12);

    let color_at = |p: Vec3| -> [f32; 4] {
        let ax = p.x.abs();
        let dy = p.y - mouth_y;
        let front = smoothstep(0.04, 0.07, p.z);
        let mut c = skin_color;
        // Warmer cheeks and nose.
        let blush = bump(((ax - 0.042) / 0.018).powi(2) + ((p.y + 0.005) / 0.015).powi(2)) * front;
        c = mix4(c, srgb(0.88, 0.58, 0.52), 0.45 * blush);
        // Lip outline: upper lip with its bow, lower lip fuller.
        let span = (1.0 - (p.x / (half_width * 1.02)).powi(2)).max(0.0);
        let bow = 0.0012 * bump((p.x / 0.004).powi(2));
        let upper_h = (0.0078 - bow) * span.powf(0.6);
        let lower_h = 0.0095 * span.powf(0.5);
        let in_lip = if dy >= 0.0 {
            smoothstep(upper_h + 0.0007, upper_h - 0.0007, dy)
        } else {
            smoothstep(lower_h + 0.0008, lower_h - 0.0008, -dy)
        };
        c = mix4(c, lip_color, in_lip * front * smoothstep(0.0, 0.05, span));
        // Eyebrows: an arch above each eye.
        let arch =
            0.049 + 0.005 * bump(((ax - 0.03) / 0.012).powi(2)) - 0.03 * (ax - 0.03).powi(2) * 10.0;
        let brow = smoothstep(0.0042, 0.0025, (p.y - arch).abs())
            * smoothstep(0.054, 0.046, ax)
            * smoothstep(0.009, 0.013, ax)
            * front;
        c = mix4(c, brow_color, 0.9 * brow);
        mix4(c, hair_color, hair_mask(p))
    };

    // --- skin ---
    let mut skin = PartMesh::new("skin", 0, true);
    let slit_x: Vec<f32> = (0..COLUMNS)
        .map(|i| shape.cast(direction(column_angle(i), phi_mouth)).x)
        .collect();
    let is_slit_column =
        |i: usize| column_angle(i).abs() < 1.0 && slit_x[i].abs() < half_width * 0.97;
    let rows = phis.len();
    let mut grid = vec![0u32; rows * COLUMNS];
    let mut lower_slit = vec![u32::MAX; COLUMNS];
    let mut slit_points = vec![Vec3::ZERO; COLUMNS];
    for (j, &phi) in phis.iter().enumerate() {
        for i in 0..COLUMNS {
            let th = column_angle(i);
            let mut p = shape.cast(direction(th, phi));
            let uv = [i as f32 / COLUMNS as f32, j as f32 / rows as f32];
            if j == slit_row && is_slit_column(i) {
                // The lips meet in a shallow groove.
                p.z -= 0.0012;
                slit_points[i] = p;
                let dark = mix4(color_at(p), srgb(0.45, 0.22, 0.22), 0.5);
                grid[j * COLUMNS + i] = skin.push(p, dark, Part::SkinUpper, uv);
                lower_slit[i] = skin.push(p, dark, Part::SkinLower, uv);
            } else {
                let below = j > slit_row && p.y < mouth_y + 0.002 && p.x.abs() < half_width * 1.5;
                let part = if below {
                    Part::SkinLower
                } else {
                    Part::SkinUpper
                };
                grid[j * COLUMNS + i] = skin.push(p, color_at(p), part, uv);
            }
        }
    }
    for j in 0..rows - 1 {
        for i in 0..COLUMNS {
            let i2 = (i + 1) % COLUMNS;
            let mut a = grid[j * COLUMNS + i];
            let mut b = grid[j * COLUMNS + i2];
            // Quads just below the lip line use the lower copies of the slit vertices.
            if j == slit_row {
                if lower_slit[i] != u32::MAX {
                    a = lower_slit[i];
                }
                if lower_slit[i2] != u32::MAX {
                    b = lower_slit[i2];
                }
            }
            let c = grid[(j + 1) * COLUMNS + i2];
            let d = grid[(j + 1) * COLUMNS + i];
            // Rows run top to bottom, columns left to right seen from the front.
            skin.quad(a, d, c, b);
        }
    }

    // --- inner lips: from the lip line back towards the teeth ---
    let inner_color = srgb(0.62, 0.28, 0.30);
    let upper_profile = [
        (0.0, 0.0),
        (0.001, -0.0035),
        (0.0025, -0.007),
        (0.0045, -0.0095),
        (0.007, -0.0115),
    ];
    let slit_cols: Vec<usize> = (0..COLUMNS).filter(|&i| is_slit_column(i)).collect();
    let mut corner_cols = Vec::new();
    if let (Some(&first), Some(&last)) = (slit_cols.first(), slit_cols.last()) {
        corner_cols.push((first + COLUMNS - 1) % COLUMNS);
        corner_cols.extend(slit_cols.iter().copied());
        corner_cols.push((last + 1) % COLUMNS);
    }
    for upper in [true, false] {
        let sign = if upper { 1.0 } else { -1.0 };
        let part = if upper {
            Part::SkinUpper
        } else {
            Part::SkinLower
        };
        let mut strip_rows: Vec<Vec<u32>> = Vec::new();
        for &i in &corner_cols {
            let (edge, base) = if is_slit_column(i) {
                let id = if upper {
                    grid[slit_row * COLUMNS + i]
                } else {
                    lower_slit[i]
                };
                (id, slit_points[i])
            } else {
                let id = grid[slit_row * COLUMNS + i];
                (id, skin.positions[id as usize])
            };
            let taper = (1.0 - (base.x / half_width).powi(2)).max(0.0).sqrt();
            let mut column = vec![edge];
            for (k, &(dy, dz)) in upper_profile.iter().enumerate().skip(1) {
                let depth = dz * taper.max(0.08);
                let q = Vec3::new(
                    base.x * (1.0 - 0.12 * k as f32 / 4.0),
                    base.y + sign * dy * taper.max(0.08),
                    base.z + depth,
                );
                let c = mix4(inner_color, srgb(0.35, 0.12, 0.13), k as f32 / 4.0);
                let id = skin.push(q, c, part, [0.5, 0.5]);
                skin.anchors[id as usize] = Some(edge);
                column.push(id);
            }
            strip_rows.push(column);
        }
        for w in strip_rows.windows(2) {
            for k in 0..upper_profile.len() - 1 {
                let (a, b, c, d) = (w[0][k], w[1][k], w[1][k + 1], w[0][k + 1]);
                if upper {
                    skin.quad(a, b, c, d);
                } else {
                    skin.quad(a, d, c, b);
                }
            }
        }
    }
    let skin_prim = skin.finish(&anatomy, &poses);

    // --- mouth cavity: the back of an ellipsoid, seen from inside ---
    let mut cavity = PartMesh::new("mouth", 1, true);
    let cav_c = Vec3::new(0.0, mouth_y - 0.004, teeth_z - 0.027);
    let cav_r = Vec3::new(0.0215, 0.019, 0.028);
    ellipsoid_mesh(
        &mut cavity,
        Ellipsoid(cav_c, cav_r, 24, 32),
        Part::Cavity,
        |q| {
            let depth = smoothstep(cav_c.z + 0.02, cav_c.z - 0.02, q.z);
            mix4(srgb(0.40, 0.14, 0.15), srgb(0.16, 0.05, 0.06), depth)
        },
        |q| q.z < teeth_z - 0.001,
    );
    let cavity_prim = cavity.finish(&anatomy, &poses);

    // --- teeth ---
    let mut teeth = PartMesh::new("teeth", 2, true);
    teeth_arch(&mut teeth, &anatomy, true);
    teeth_arch(&mut teeth, &anatomy, false);
    let teeth_prim = teeth.finish(&anatomy, &poses);

    // --- tongue ---
    let mut tongue = PartMesh::new("tongue", 3, true);
    let t_c = Vec3::new(0.0, mouth_y - 0.0115, teeth_z - 0.024);
    ellipsoid_mesh(
        &mut tongue,
        Ellipsoid(t_c, Vec3::new(0.02, 0.0075, 0.024), 20, 28),
        Part::Tongue,
        |q| {
            let top = smoothstep(t_c.y - 0.002, t_c.y + 0.006, q.y);
            mix4(srgb(0.62, 0.26, 0.28), srgb(0.80, 0.42, 0.44), top)
        },
        |_| true,
    );
    let tongue_prim = tongue.finish(&anatomy, &poses);

    // --- eyes ---
    let mut eyes = PartMesh::new("eyes", 4, false);
    for side in [-1.0f32, 1.0] {
        let c = Vec3::new(side * EYE_X, EYE_Y, EYE_Z - 0.0025);
        ellipsoid_mesh(
            &mut eyes,
            Ellipsoid(c, Vec3::splat(EYE_R), 24, 32),
            Part::Rigid,
            |q| {
                // Looking straight ahead, slightly converged.
                let axis = Vec3::new(-side * 0.06, 0.0, 1.0).normalize();
                let cosang = (q - c).normalize().dot(axis);
                let ang = cosang.clamp(-1.0, 1.0).acos();
                if ang < 0.2 {
                    srgb(0.03, 0.02, 0.02)
                } else if ang < 0.46 {
                    mix4(
                        srgb(0.36, 0.24, 0.14),
                        srgb(0.20, 0.12, 0.07),
                        (ang - 0.2) / 0.26,
                    )
                } else if ang < 0.5 {
                    srgb(0.15, 0.10, 0.07)
                } else {
                    srgb(0.93, 0.91, 0.88)
                }
            },
            |_| true,
        );
    }
    let eyes_prim = eyes.finish(&anatomy, &poses);

    let materials = vec![
        Material {
            name: "skin".into(),
            base_color: [1.0; 4],
            texture: None,
        },
        Material {
            name: "mouth".into(),
            base_color: [1.0; 4],
            texture: None,
        },
        Material {
            name: "teeth".into(),
            base_color: [1.0; 4],
            texture: None,
        },
        Material {
            name: "tongue".into(),
            base_color: [1.0; 4],
            texture: None,
        },
        Material {
            name: "eyes".into(),
            base_color: [1.0; 4],
            texture: None,
        },
    ];
    HeadModel {
        primitives: vec![skin_prim, cavity_prim, teeth_prim, tongue_prim, eyes_prim],
        materials,
        source: TargetSource::Procedural,
        missing_visemes: Vec::new(),
    }
}

/// A UV-sphere ellipsoid; `keep` filters which latitude/longitude cells are emitted.
/// Centre, radii, rings and segments of a UV-sphere ellipsoid.
struct Ellipsoid(Vec3, Vec3, usize, usize);

fn ellipsoid_mesh(
    mesh: &mut PartMesh,
    Ellipsoid(c, r, rings, segments): Ellipsoid,
    part: Part,
    color: impl Fn(Vec3) -> [f32; 4],
    keep: impl Fn(Vec3) -> bool,
) {
    let start = mesh.positions.len() as u32;
    for j in 0..=rings {
        let phi = std::f32::consts::PI * (j as f32 / rings as f32 - 0.5);
        for i in 0..=segments {
            let th = std::f32::consts::TAU * i as f32 / segments as f32;
            let q = c + r * direction(th, -phi);
            mesh.push(
                q,
                color(q),
                part,
                [i as f32 / segments as f32, j as f32 / rings as f32],
            );
        }
    }
    let row = segments as u32 + 1;
    for j in 0..rings as u32 {
        for i in 0..segments as u32 {
            let a = start + j * row + i;
            let (b, cc, d) = (a + 1, a + row + 1, a + row);
            let centre = (mesh.positions[a as usize] + mesh.positions[cc as usize]) * 0.5;
            if keep(centre) {
                mesh.quad(a, d, cc, b);
            }
        }
    }
}

/// Upper or lower dental arch: a curved band of teeth with gums behind the lips.
fn teeth_arch(mesh: &mut PartMesh, a: &Anatomy, upper: bool) {
    const STEPS: usize = 72;
    let sign = if upper { 1.0 } else { -1.0 };
    let part = if upper {
        Part::UpperTeeth
    } else {
        Part::LowerTeeth
    };
    let front_z = if upper { a.teeth_z } else { a.teeth_z - 0.0025 };
    let half = if upper { 0.0235 } else { 0.021 };
    // Tooth widths from the middle outwards (incisors, canine, premolars, molar).
    let widths: &[f32] = if upper {
        &[0.0085, 0.0066, 0.0076, 0.007, 0.0068, 0.01]
    } else {
        &[0.0054, 0.006, 0.007, 0.007, 0.007, 0.011]
    };
    let edge_y = a.mouth_y + if upper { -0.0012 } else { -0.0006 };
    let crown = if upper { 0.0105 } else { 0.0095 };
    let gum = if upper { 0.005 } else { 0.003 };
    let white = srgb(0.93, 0.91, 0.84);
    let gum_color = srgb(0.78, 0.42, 0.44);
    let gap = srgb(0.55, 0.5, 0.45);
    // Arc-length along the arch from the middle, for tooth boundaries.
    let arch = |s: f32| -> Vec3 {
        let x = half * s;
        let z = front_z - 0.019 * s * s - 0.006 * s.powi(4);
        Vec3::new(x, 0.0, z)
    };
    let rows = 7;
    let start = mesh.positions.len() as u32;
    let mut length = 0.0f32;
    let mut prev = arch(-1.0);
    let mut lengths = Vec::new();
    for i in 0..=STEPS {
        let s = -1.0 + 2.0 * i as f32 / STEPS as f32;
        let p = arch(s);
        length += (p - prev).length();
        prev = p;
        lengths.push(length);
    }
    let mid = lengths[STEPS / 2];
    for (i, &arc) in lengths.iter().enumerate() {
        let s = -1.0 + 2.0 * i as f32 / STEPS as f32;
        let base = arch(s);
        let outward = {
            let ahead = arch((s + 0.01).min(1.0)) - arch((s - 0.01).max(-1.0));
            Vec3::new(ahead.z, 0.0, -ahead.x).normalize_or_zero() * -1.0
        };
        // Position within its tooth: 0 at a boundary, 1 at the middle of a tooth.
        let mut along = (arc - mid).abs();
        let mut within = 0.0;
        for &w in widths {
            if along < w {
                within = (along / w * std::f32::consts::PI).sin();
                break;
            }
            along -= w;
        }
        let rounded = within.powf(0.35);
        let tip = edge_y - sign * 0.0 + sign * 0.0013 * (1.0 - rounded);
        let bulge = 0.0007 * rounded;
        let front = s.abs() < 0.4;
        let heights = [
            0.0,
            0.0008,
            0.3 * crown,
            0.7 * crown,
            crown,
            crown + gum * 0.5,
            crown + gum,
        ];
        let depth = [0.0, 0.0, 0.0, 0.0, 0.0, -0.0003, -0.001];
        let mut column = Vec::new();
        for k in 0..rows {
            let y = tip + sign * heights[k];
            let p = base
                + outward
                    * (bulge * if k < 5 { 1.0 } else { 0.0 } + depth[k]
                        - if k == 0 { 0.0008 } else { 0.0 })
                + Vec3::Y * y;
            let mut c = if k >= 5 {
                gum_color
            } else {
                mix4(gap, white, rounded.powf(0.2))
            };
            if !front {
                c = mix4(c, srgb(0.6, 0.55, 0.5), 0.3);
            }
            column.push(mesh.push(p, c, part, [s, k as f32 / rows as f32]));
        }
        // Back (tongue) side of the band.
        for k in (0..rows).rev() {
            let y = tip + sign * heights[k];
            let p = base - outward * (0.0065 - 0.002 * (k as f32 / rows as f32)) + Vec3::Y * y;
            let c = if k >= 5 {
                gum_color
            } else {
                mix4(gap, white, rounded.powf(0.3))
            };
            column.push(mesh.push(p, c, part, [s, 1.0]));
        }
        let _ = column;
    }
    let per = (2 * rows) as u32;
    for i in 0..STEPS as u32 {
        for k in 0..per - 1 {
            let a0 = start + i * per + k;
            let b0 = a0 + per;
            if upper {
                mesh.quad(a0, b0, b0 + 1, a0 + 1);
            } else {
                mesh.quad(a0, a0 + 1, b0 + 1, b0);
            }
        }
    }
}
