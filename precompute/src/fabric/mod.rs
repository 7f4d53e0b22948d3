//! Fiber-level fabric geometry.
//!
//! A fabric is an [`Exemplar`]: a set of [`Fiber`] polylines, each belonging to a yarn, plus
//! how the exemplar tiles the plane. Procedural exemplars are built from a weave draft
//! ([`weave`]) and procedural yarns ([`yarn`]) by [`exemplar`]; real fiber data is read and
//! written by [`fiber_io`]. Material presets resembling the 2017 paper's fabrics live in
//! [`presets`].
//!
//! Geometry is `f32` (it feeds ray casting and, later, the GPU); lengths are centimetres. The
//! fabric lies in the xy plane, warp yarns run along +y, weft yarns along +x, and the top face
//! (the side seen from the default camera) faces +z.

pub mod colour_order;
pub mod exemplar;
pub mod fiber_io;
pub mod presets;
pub mod weave;
pub mod wif;
pub mod yarn;

use glam::{Vec2, Vec3};

/// Which set of yarns a yarn belongs to; warp and weft may carry different materials.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum YarnRole {
    /// Runs along +y.
    Warp,
    /// Runs along +x.
    Weft,
    /// Imported fibers with no weave role.
    Other,
}

/// One yarn of an exemplar: its role and the index of its material in the scene's material list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Yarn {
    pub role: YarnRole,
    pub material: u32,
}

/// One fiber: a polyline of control points (at least two) with a constant radius.
#[derive(Debug, Clone, PartialEq)]
pub struct Fiber {
    pub points: Vec<Vec3>,
    pub radius: f32,
    /// Index into [`Exemplar::yarns`].
    pub yarn: u32,
}

/// A straight piece of fiber between two consecutive control points, with everything a hit
/// needs to shade it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub a: Vec3,
    pub b: Vec3,
    pub radius: f32,
    /// Index into [`Exemplar::fibers`].
    pub fiber: u32,
    /// Index into [`Exemplar::yarns`].
    pub yarn: u32,
}

impl Segment {
    #[must_use]
    pub fn midpoint(&self) -> Vec3 {
        0.5 * (self.a + self.b)
    }

    /// Unit direction from `a` to `b` (the fiber tangent, x axis of the fiber frame).
    #[must_use]
    pub fn tangent(&self) -> Vec3 {
        (self.b - self.a).normalize_or_zero()
    }

    #[must_use]
    pub fn length(&self) -> f32 {
        (self.b - self.a).length()
    }
}

/// How an exemplar covers the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Tiling {
    /// The exemplar repeats with this period along x and y (cm). Fibers may extend past the
    /// period rectangle `[0, period.x) x [0, period.y)`; their continuation in the next copy
    /// joins them seamlessly.
    Periodic { period: Vec2 },
    /// The fibers are used exactly as given, once.
    AsIs,
}

/// Division of one exemplar period into blocks (the unit a pattern map addresses, paper
/// section 6.4) along x and y.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockGrid {
    pub nx: u32,
    pub ny: u32,
}

/// A fiber-level piece of fabric: fibers, yarns, and how it tiles.
#[derive(Debug, Clone, PartialEq)]
pub struct Exemplar {
    pub fibers: Vec<Fiber>,
    pub yarns: Vec<Yarn>,
    pub tiling: Tiling,
    pub blocks: BlockGrid,
}

impl Exemplar {
    /// All segments of all fibers, in fiber order (segment ids index this list).
    #[must_use]
    pub fn segments(&self) -> Vec<Segment> {
        let mut out = Vec::with_capacity(self.segment_count());
        for (f, fiber) in self.fibers.iter().enumerate() {
            for pair in fiber.points.windows(2) {
                out.push(Segment {
                    a: pair[0],
                    b: pair[1],
                    radius: fiber.radius,
                    fiber: f as u32,
                    yarn: fiber.yarn,
                });
            }
        }
        out
    }

    #[must_use]
    pub fn segment_count(&self) -> usize {
        self.fibers.iter().map(|f| f.points.len().saturating_sub(1)).sum()
    }

    /// Axis-aligned bounds of the fibers including their radius; `None` if there are none.
    #[must_use]
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for fiber in &self.fibers {
            for &p in &fiber.points {
                lo = lo.min(p - fiber.radius);
                hi = hi.max(p + fiber.radius);
            }
        }
        lo.x.is_finite().then_some((lo, hi))
    }

    /// Material index of a yarn.
    #[must_use]
    pub fn material_of_yarn(&self, yarn: u32) -> u32 {
        self.yarns[yarn as usize].material
    }
}
