//! Procedural base meshes: `swatch`, `drape` and `cushion`.
//!
//! All three are height fields z = h(x, y) over the rectangle [-W/2, W/2] × [-H/2, H/2] (cm),
//! triangulated as a regular grid, normals from the surface gradient, and UVs already in
//! centimetres (use `cm_per_uv = 1`):
//! - `swatch`: h = 0, 8 × 8 quads, UV = (x, y) exactly, so the shell maps the flat fabric onto itself;
//! - `drape`: a cloth hanging over a round support: a flat top that falls off smoothly towards the
//!   border, with six radial folds whose depth grows away from the centre; 64 × 64 quads;
//! - `cushion`: a pillow top: a bulge vanishing at the border seam with a shallow tufting dimple in
//!   the middle; 64 × 64 quads.
//!
//! For the curved ones u is arc length along the row (constant y) from the x = 0 column, and v is
//! arc length along the column from the y = 0 row, so the weave is close to unstretched; a curved
//! surface cannot be flattened exactly, and the residual distortion is a few percent at most.
//! Shapes scale with the size; the tightest curvature radius is about 0.15 × min(W, H), which bounds
//! the thickness a shell over them can have before it folds (the build reports an inverted prism).

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
        let scale = half.min_element();
        let source = format!("builtin:{name}");
        Ok(match name {
            "swatch" => grid(source, size, 8, |_| 0.0, true),
            "drape" => grid(source, size, 64, |p| drape_height(p, scale), false),
            _ => grid(source, size, 64, |p| cushion_height(p, half), false),
        })
    }
}

/// A cloth over a round support of radius 0.45·L (L = half the shorter side).
fn drape_height(p: DVec2, scale: f64) -> f64 {
    let support = 0.45 * scale;
    let r2 = p.length_squared() / (support * support);
    let fall = r2 * r2 / (1.0 + r2 * r2); // 0 on top, -> 1 far out
    let fold_weight = r2 * r2 * r2 / (1.0 + r2 * r2 * r2);
    let theta = p.y.atan2(p.x);
    let folds = (6.0 * theta).cos() + 0.35 * (4.0 * theta + 1.0).cos();
    -0.6 * scale * fall + 0.06 * scale * fold_weight * folds
}

/// A pillow top: (1 - s⁴)(1 - t⁴) bulge, zero at the seam, with a dimple in the middle.
fn cushion_height(p: DVec2, half: DVec2) -> f64 {
    let scale = half.min_element();
    let (s, t) = (p.x / half.x, p.y / half.y);
    let bulge = (1.0 - s.powi(4)) * (1.0 - t.powi(4));
    let dimple = (-(p.length_squared()) / (0.15 * scale).powi(2)).exp();
    0.25 * scale * bulge - 0.04 * scale * dimple
}

/// A `quads × quads` grid over the rectangle of `size`, lifted by `height`.
fn grid(source: String, size: DVec2, quads: u32, height: impl Fn(DVec2) -> f64, flat: bool) -> BaseMesh {
    let side = quads + 1;
    let coordinate = |i: u32, extent: f64| extent * (f64::from(i) / f64::from(quads) - 0.5);
    let step = 1e-5 * size.min_element();
    let gradient = |p: DVec2| {
        let dx = (height(p + DVec2::X * step) - height(p - DVec2::X * step)) / (2.0 * step);
        let dy = (height(p + DVec2::Y * step) - height(p - DVec2::Y * step)) / (2.0 * step);
        DVec2::new(dx, dy)
    };
    // Arc length from 0 to `to` along one axis (Simpson's rule, fine enough for these smooth shapes).
    let arc = |fixed: f64, to: f64, along_x: bool| {
        let steps = 64;
        let h = to / f64::from(steps);
        let speed = |s: f64| {
            let p = if along_x { DVec2::new(s, fixed) } else { DVec2::new(fixed, s) };
            let g = gradient(p);
            (1.0 + if along_x { g.x * g.x } else { g.y * g.y }).sqrt()
        };
        let mut sum = speed(0.0) + speed(to);
        for k in 1..steps {
            sum += speed(h * f64::from(k)) * if k % 2 == 1 { 4.0 } else { 2.0 };
        }
        sum * h / 3.0
    };

    let mut positions = Vec::with_capacity((side * side) as usize);
    let mut normals = Vec::with_capacity(positions.capacity());
    let mut uvs = Vec::with_capacity(positions.capacity());
    for j in 0..side {
        for i in 0..side {
            let p = DVec2::new(coordinate(i, size.x), coordinate(j, size.y));
            if flat {
                positions.push(Vec3::new(p.x as f32, p.y as f32, 0.0));
                normals.push(Vec3::Z);
                uvs.push(Vec2::new(p.x as f32, p.y as f32));
            } else {
                let g = gradient(p);
                positions.push(p.extend(height(p)).as_vec3());
                normals.push(DVec3::new(-g.x, -g.y, 1.0).normalize().as_vec3());
                uvs.push(DVec2::new(arc(p.y, p.x, true), arc(p.x, p.y, false)).as_vec2());
            }
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
