//! Procedural base meshes: `swatch`, `drape` and `cushion`.
//!
//! All three are height fields z = h(x, y) over the rectangle [-W/2, W/2] × [-H/2, H/2] (cm),
//! triangulated as a regular grid, normals from the surface gradient, and UVs already in
//! centimetres (use `cm_per_uv = 1`):
//! - `swatch`: h = 0, 8 × 8 quads, UV = (x, y) exactly, so the shell maps the flat fabric onto itself;
//! - `drape`: a towel hanging over a rod along the y axis: a rounded top that falls away on both
//!   sides (up to about 55°), with folds running down the hanging parts; 64 × 64 quads;
//! - `cushion`: a pillow top: a bulge vanishing at the border seam with a shallow tufting dimple in
//!   the middle; 64 × 64 quads.
//!
//! For the curved ones u is arc length along the row (constant y) from the x = 0 column, and v is
//! arc length along the column from the y = 0 row, so the weave is close to unstretched: the
//! drape is nearly developable (a cylinder-like fall plus shallow folds), and no mesh edge's UV
//! length differs from its world length by more than about 10 % on either shape.
//! Shapes scale with the size; their tightest concave curvature bounds the shell thickness to
//! about 0.1 × min(W, H) (thicker shells fold over and the build reports an inverted prism).

use glam::{DVec2, DVec3, Vec2, Vec3};

use super::{BaseMesh, ShellError};

/// Smallest builtin side, in centimetres.
pub const MIN_BUILTIN_SIDE_CM: f32 = 1e-3;
/// Largest builtin side, in centimetres.
pub const MAX_BUILTIN_SIDE_CM: f32 = 1e4;

impl BaseMesh {
    /// Names accepted by [`BaseMesh::builtin`].
    pub const BUILTIN_NAMES: &'static [&'static str] = &["swatch", "drape", "cushion"];

    /// A procedural mesh of `size_cm = [width, height]`, centred on the origin, UVs in cm.
    pub fn builtin(name: &str, size_cm: [f32; 2]) -> Result<BaseMesh, ShellError> {
        if !Self::BUILTIN_NAMES.contains(&name) {
            return Err(ShellError::UnknownBuiltin {
                name: name.to_owned(),
                valid: Self::BUILTIN_NAMES.join(", "),
            });
        }
        if !size_cm.iter().all(|s| (MIN_BUILTIN_SIDE_CM..=MAX_BUILTIN_SIDE_CM).contains(s)) {
            return Err(ShellError::BuiltinSize {
                name: name.to_owned(),
                size_cm,
                min_cm: MIN_BUILTIN_SIDE_CM,
                max_cm: MAX_BUILTIN_SIDE_CM,
            });
        }
        let size = DVec2::new(f64::from(size_cm[0]), f64::from(size_cm[1]));
        let half = size * 0.5;
        let source = format!("builtin:{name}");
        Ok(match name {
            "swatch" => grid(source, size, 8, |_| 0.0, Unfold::Identity),
            "drape" => grid(source, size, 64, |p| drape_height(p, half), Unfold::AlongAxes),
            _ => grid(source, size, 64, |p| cushion_height(p, half), Unfold::AlongAxes),
        })
    }
}

/// A towel over a horizontal rod along the y axis: a rounded top of radius about `0.45·L` (`L` =
/// half the shorter side) whose sides fall away at up to about 55°, with folds that run down the
/// hanging parts and deepen away from the rod.
fn drape_height(p: DVec2, half: DVec2) -> f64 {
    let scale = half.min_element();
    let rod = 0.3 * scale;
    let q = (p.x / rod).powi(2);
    let fall = 0.45 * scale * ((1.0 + q).sqrt() - 1.0);
    let fold_depth = 0.05 * scale * q / (1.0 + q);
    let k = std::f64::consts::PI / half.y; // one fold period per half height
    let folds = (3.0 * k * p.y + 0.4).cos() + 0.3 * (5.0 * k * p.y + 0.15 * p.x / rod).sin();
    -fall + fold_depth * folds
}

/// A pillow top: (1 - s⁴)(1 - t⁴) bulge, zero at the seam, with a dimple in the middle.
fn cushion_height(p: DVec2, half: DVec2) -> f64 {
    let scale = half.min_element();
    let (s, t) = (p.x / half.x, p.y / half.y);
    let bulge = (1.0 - s.powi(4)) * (1.0 - t.powi(4));
    let dimple = (-(p.length_squared()) / (0.15 * scale).powi(2)).exp();
    0.25 * scale * bulge - 0.04 * scale * dimple
}

/// How a builtin's UVs (in cm) follow its surface.
#[derive(Clone, Copy)]
enum Unfold {
    /// UV = (x, y): the flat swatch.
    Identity,
    /// u = arc length along the row from x = 0, v = arc length along the column from y = 0.
    AlongAxes,
}

/// A `quads × quads` grid over the rectangle of `size`, lifted by `height`.
fn grid(source: String, size: DVec2, quads: u32, height: impl Fn(DVec2) -> f64, unfold: Unfold) -> BaseMesh {
    let side = quads + 1;
    let coordinate = |i: u32, extent: f64| extent * (f64::from(i) / f64::from(quads) - 0.5);
    let step = 1e-5 * size.min_element();
    let gradient = |p: DVec2| {
        let dx = (height(p + DVec2::X * step) - height(p - DVec2::X * step)) / (2.0 * step);
        let dy = (height(p + DVec2::Y * step) - height(p - DVec2::Y * step)) / (2.0 * step);
        DVec2::new(dx, dy)
    };
    // Arc length of the surface over the segment from `from` to `to` (Simpson's rule).
    let arc = |from: DVec2, to: DVec2| {
        let steps = 64;
        let direction = to - from;
        let speed = |t: f64| {
            (direction.length_squared() + gradient(from + direction * t).dot(direction).powi(2)).sqrt()
        };
        let mut sum = speed(0.0) + speed(1.0);
        for k in 1..steps {
            sum += speed(f64::from(k) / f64::from(steps)) * if k % 2 == 1 { 4.0 } else { 2.0 };
        }
        sum / f64::from(3 * steps)
    };
    let signed = |value: f64, sign: f64| if sign < 0.0 { -value } else { value };

    let mut positions = Vec::with_capacity((side * side) as usize);
    let mut normals = Vec::with_capacity(positions.capacity());
    let mut uvs = Vec::with_capacity(positions.capacity());
    for j in 0..side {
        for i in 0..side {
            let p = DVec2::new(coordinate(i, size.x), coordinate(j, size.y));
            match unfold {
                Unfold::Identity => {
                    positions.push(Vec3::new(p.x as f32, p.y as f32, 0.0));
                    normals.push(Vec3::Z);
                    uvs.push(Vec2::new(p.x as f32, p.y as f32));
                    continue;
                }
                Unfold::AlongAxes => {
                    let u = signed(arc(DVec2::new(0.0, p.y), p), p.x);
                    let v = signed(arc(DVec2::new(p.x, 0.0), p), p.y);
                    uvs.push(DVec2::new(u, v).as_vec2());
                }
            }
            let g = gradient(p);
            positions.push(p.extend(height(p)).as_vec3());
            normals.push(DVec3::new(-g.x, -g.y, 1.0).normalize().as_vec3());
        }
    }
    let mut triangles = Vec::with_capacity((2 * quads * quads) as usize);
    for j in 0..quads {
        for i in 0..quads {
            let a = j * side + i;
            let (b, c, d) = (a + 1, a + side + 1, a + side);
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    BaseMesh { positions, normals, uvs, triangles, source }
}
