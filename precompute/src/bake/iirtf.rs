//! Per-cell IIRTF matrices by path tracing (paper section 4.2).
//!
//! The IIRTF T(ω0, ω1, x) is the radiance arriving at x from −ω1 that left a directional light
//! of unit irradiance from ω0 and touched at least one fiber. Its SH matrix over a cell C is
//! `a_C[j0, j1] = ∫∫ T(ω0, ω1, C) Y_j0(ω0) Y_j1(ω1) dω0 dω1`, with T(·, ·, C) the mean of T over
//! the midpoints μ_k of the segments in C (the paper), or with exposed starts
//! (`BakeSettings::exposed_starts`) over the points of C's fibers an eye sees
//! ([`TransferSampler::exposed_start`]), the points the method shades.
//!
//! How it works: each path draws a segment k of the cell uniformly and ω1 uniformly on the
//! sphere (pdf 1/4π), these and its first light sample stratified over the cell's paths
//! ([`path_strata`]: randomly shifted low-discrepancy sequences), and walks from μ_k or its
//! exposed start (in the
//! central copy of the fabric tiled over the whole plane, no ground) toward ω1, ignoring k's
//! own fiber on the first ray ([`TransferSampler::sample`]), choosing and sampling each event's
//! lobe without the colours and weighing the path at the materials' colours afterwards (the
//! colour-free walk the recolouring basis differentiates, so a bake and a live recolouring share
//! their paths). At each fiber event it draws a
//! light direction ω0 from that fiber's scattering function and casts a shadow ray; ω0 counts
//! if it lies in the light domain (the upper hemisphere, as in the paper: T is zero for light
//! from below;
//! [`LightDomain::Sphere`] takes the whole sphere). Light reaching μ_k without touching a fiber
//! is never counted, so only scattered light enters. The path's estimate of every coefficient
//! is `Σ_events w · Y_j0(ω0) Y_j1(ω1)` with `w = throughput · S cos θ0 / (p(ω0) p(ω1))` (p(k)
//! cancels the 1/|C|); the per-coefficient standard error comes from the same paths. (The
//! paper draws one uniform ω0 per path and lights the whole path from it; the fiber lobes are
//! narrow, so that estimate is far noisier for the same rays.)
//!
//! Storage: [`CellTransfer::matrix`] is `(L+1)²` rows (output j1) by `(L+1)²` columns
//! (input j0), row-major, so the paper's `c_T = A_C c_d` is [`CellTransfer::apply`]: row j1 of
//! the result is `Σ_j0 a_C[j0, j1] c_d[j0]`. Entries are held in f32 from the moment a cell is
//! finished (their noise is far above f32 rounding), and a cell with no segment holds no entries
//! at all (it transfers nothing): the in-memory form is the stored one, so a bake of a large
//! fabric neither holds its matrices in f64 nor copies them to write them.
//! Determinism: path `p` of cell `c` draws from `pixel_rng(seed ^ mix(c), p)` (its stratified
//! start from [`path_strata`], whose shift is drawn once per cell) and each cell's
//! sums are accumulated in path order by one worker, so results do not depend on threads.
//! Parallelism: one worker per rayon thread, all sharing one [`TransferSampler`] (its fiber
//! scene is read-only; a copy per worker would grow with the machine's core count), pulling
//! whole cells from a shared counter.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::DVec3;
use rand::Rng;
use rayon::prelude::*;

use super::cells::CellGrid;
use super::settings::{BakeSettings, CellPaths};
use super::{Cancel, Cancelled, Progress};
use crate::Rgb;
use crate::bcsdf::{COLOUR_FREE_C_R, Lobe, Material};
use crate::fabric::Exemplar;
use crate::pathtrace::integrator::{pixel_rng, russian_roulette};
use crate::raycast::{Extent, FiberScene, SceneError};
use crate::sh::{sh_count, sh_eval};

/// Tries for a point an eye sees before a path starts at its segment's midpoint
/// ([`TransferSampler::exposed_start`]).
pub const EXPOSED_START_TRIES: usize = 16;

/// Tries for a point of a segment an eye sees before its segment cell is left empty
/// ([`TransferSampler::eye_sees`]; a multiple of [`EXPOSED_START_TRIES`]).
pub const EYE_SEES_TRIES: usize = 64;

/// Mixed into a segment cell's stream for [`TransferSampler::eye_sees`], so that its draws are
/// not its first path's.
const EYE_SEES_STREAM: u64 = 0xE7E5_EE50_0000_0001;

/// Most scattering events of an IIRTF path (Russian roulette ends nearly all far earlier).
pub const MAX_DEPTH: u32 = 1000;

/// The TT factor at which the colour-free walk's Russian roulette weighs paths: high, so that
/// paths live as long as the whitest yarns need (a weight at TT factor τ is the colour-free
/// weight times τ^K; at τ = 1 it grows by at most `(1 / 0.95)^K` over the roulette's).
pub const COLOUR_FREE_ROULETTE_ALBEDO: f64 = 0.95;

/// Where light directions ω0 are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum LightDomain {
    /// The upper hemisphere (z > 0), as in the paper: T is taken as zero for light from below.
    #[default]
    UpperHemisphere,
    /// The whole sphere (light from below the fabric too).
    Sphere,
}

#[derive(Debug, thiserror::Error)]
pub enum IirtfError {
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
    #[error("IIRTF scene: {0}")]
    Scene(#[from] SceneError),
    #[error("the exemplar has {yarns} yarns but {materials} yarn materials were given")]
    MaterialCount { yarns: usize, materials: usize },
    #[error("the cell grid was built for {grid} segments but the exemplar has {exemplar}")]
    GridMismatch { grid: usize, exemplar: usize },
}

/// One cell's IIRTF matrix and its noise; both empty for a cell with no segment.
///
/// Serialized in this field order, which is the bake file's layout.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CellTransfer {
    /// Paths traced (0 for an empty cell).
    pub paths: usize,
    /// `matrix[j1 * n + j0] = a_C[j0, j1]`, n = (L+1)², RGB.
    pub matrix: Vec<[f32; 3]>,
    /// Standard error of each entry (same layout), estimated as if the paths were independent:
    /// their starts are stratified ([`path_strata`]), so this is an upper bound.
    pub std_error: Vec<[f32; 3]>,
    /// The forward chains' strength (`BakeSettings::fiber_lobes`; empty without it, and in a
    /// cell that keeps all of its transfer in its matrix): the SH coefficients, at
    /// [`LOBE_SH_ORDER`], over light directions ω0 of `F(ω0) = ∫ T_fwd(ω0, ω1, C) dω1`, the
    /// radiance transmitted by every fiber on its way arriving in the cell from a
    /// unit-irradiance light, integrated over its arrival directions ω1; RGB.
    pub forward: Vec<[f32; 3]>,
    /// `∫∫ T_fwd(ω0, ω1, C) (ω0·ω1) dω0 dω1`: over `√(4π) forward[0]`, the mean cosine between
    /// the light's direction and the one its forward chains arrive from, whose sharpness
    /// ([`forward_sharpness`]) decides whether the cell keeps its lobes
    /// ([`forward_lobe_min_sharpness`]). Zero without lobes.
    pub forward_cosine: [f32; 3],
    /// The light reflected at least once (everything but the forward chains), as `forward`:
    /// `R(ω0) = ∫ T_refl(ω0, ω1, C) dω1` at [`LOBE_SH_ORDER`]; empty exactly when `forward` is.
    pub reflected: Vec<[f32; 3]>,
    /// Where the forward chains arrive from, against the light's direction, in the fiber frame
    /// of the segment they arrive at ([`FiberOffset`]): [`LOBE_SHAPE_LEN`] sums over the
    /// cell's paths, each weighted by the connection's forward share (summed over channels)
    /// and divided by the paths: per light-elevation node ([`LOBE_AZIMUTH_BINS`]) `cos kΔφ`
    /// and `toward_up · sin kΔφ` for k = 1..=[`LOBE_AZIMUTH_TERMS`], then those nodes' totals,
    /// then the totals of the nodes of the light's angle to the fiber
    /// ([`LOBE_LONGITUDINAL_BINS`]), then per such node `cos kΔθ`, `sin kΔθ` for
    /// k = 1..=[`LOBE_FOURIER_TERMS`] ([`FiberOffset::accumulate`]). Each node's sums over its
    /// total are the means the lobe is shaded with
    /// ([`crate::shading::multiple::FiberLobe::angles`]). Empty without lobes.
    pub forward_shape: Vec<f32>,
    /// As `forward_shape`, for the reflected light.
    pub reflected_shape: Vec<f32>,
}

/// SH order of the fiber lobes' strength over light directions (`BakeSettings::fiber_lobes`),
/// whatever the transfer's order: the strength is a function of the light's direction alone,
/// and peaked on the silk satin (over the 100 hard configurations, order 6 instead of 4 cut
/// the CPU method's multiple-scattering error from 19.3% to 17.2%, `docs/BENCHMARKS.md`). The
/// highest the SH rotation and the GPU hold.
pub const LOBE_SH_ORDER: usize = crate::sh::EULER_MAX_ORDER;

/// Fourier terms of a lobe's longitudinal shape. The series is Jackson-smoothed
/// (`shading::gamma::jackson_factor`) so that it stays a density, and the smoothing kernel is
/// about 180°/(K+1) wide: at 12 terms its 14° of blur spread the sharp arrival offsets of
/// raking light on the silk satin and held its multiple scattering 67–97% bright (silk 24 and
/// 59 of the accuracy run); at 24 terms, 7°, 49% (`docs/BENCHMARKS.md`). A chain of
/// transmissions through silk spreads about 10 degrees per fiber.
pub const LOBE_FOURIER_TERMS: usize = 24;

/// Fourier terms of a lobe's azimuthal shape, about the light's azimuth around the fiber, at
/// each elevation node: a forward fan is about 20 degrees wide on silk. Jackson-smoothed like
/// the longitudinal series, so its kernel is about 7° wide at 24 terms; at 12 terms its 14°
/// held the silk's raking multiple scattering about 8 points brighter (silk 24 and 59 of the
/// accuracy run, `docs/BENCHMARKS.md`), though the shaded fiber's own TT lobe (a von Mises
/// density, whose coefficients fall as `e^{−k²/2κ}`) smooths it again.
pub const LOBE_AZIMUTH_TERMS: usize = 24;

/// Light elevations about the fiber ([`fiber_elevation`], 0 at the fiber's horizon to 1
/// overhead) at which a lobe keeps its azimuthal shape: evenly spaced nodes, between which the
/// shape is interpolated linearly ([`elevation_hats`]). Where reflected light arrives from about
/// the fiber depends on where the light stands about it: a raking light's comes back from the
/// far side far more than an overhead light's (on the silk satin at 78°, a shape averaged over
/// all light directions doubled its multiple scattering). Taken about the fiber, not above the
/// fabric: a low light along the fiber stands overhead in the fiber's normal plane, and nodes
/// of the fabric's elevation mixed its shape into a raking light's across the fiber. Nine
/// nodes, 0.125 apart: on the silk satin's backlit raking configuration 49 (light at elevation
/// 0.2 about the warp floats) the lattice's multiple scattering was +13.0% at five nodes, +6.6%
/// at nine and +6.7% at seventeen (`docs/BENCHMARKS.md`).
pub const LOBE_AZIMUTH_BINS: usize = 9;

/// The light's elevation about a fiber of unit tangent t: the cosine of the angle, in the
/// plane normal to t, between the light's direction ω and the fabric's up (+z) projected into
/// that plane, `(ω·z − (ω·t) t_z) / (|ω × t| |t_xy|)`, clamped to [0, 1] (1 overhead, 0 at the
/// fiber's horizon). Where either projection vanishes (ω or t vertical to within 1e-6), ω's
/// own `z`.
#[must_use]
pub fn fiber_elevation(tangent: DVec3, dir: DVec3) -> f64 {
    let scale = dir.cross(tangent).length() * tangent.truncate().length();
    if scale < 1e-6 {
        return dir.z.clamp(0.0, 1.0);
    }
    ((dir.z - dir.dot(tangent) * tangent.z) / scale).clamp(0.0, 1.0)
}

/// Values of the sine of the light's angle to the fiber, `ω0·t` (−1 to 1), at which a lobe
/// keeps its longitudinal shape: evenly spaced nodes, between which the shape is interpolated
/// linearly ([`longitudinal_hats`]). Where light arrives from along the fiber depends on the
/// light's own angle to it: light across the fiber comes back spread about its own angle, light
/// along it only from below that angle (|θ| ≤ 90°). A longitudinal shape pooled over all light
/// directions held the silk satin's raking backlit multiple scattering about 20% bright
/// (configuration 49 of the accuracy run: shapes taken from the light's own direction alone
/// brought the per-cell transfer from +19% to +0.4%, `docs/BENCHMARKS.md`).
pub const LOBE_LONGITUDINAL_BINS: usize = 7;

/// The two [`LOBE_AZIMUTH_BINS`] nodes around elevation `z` ([`fiber_elevation`], clamped to
/// [0, 1]) and their linear interpolation weights, which sum to 1.
#[must_use]
pub fn elevation_hats(z: f64) -> [(usize, f64); 2] {
    node_hats(z, LOBE_AZIMUTH_BINS)
}

/// The two [`LOBE_LONGITUDINAL_BINS`] nodes around `along = ω0·t` (clamped to [−1, 1]) and
/// their linear interpolation weights, which sum to 1.
#[must_use]
pub fn longitudinal_hats(along: f64) -> [(usize, f64); 2] {
    node_hats(0.5 * (along + 1.0), LOBE_LONGITUDINAL_BINS)
}

/// The two of `bins` evenly spaced nodes on [0, 1] around `x` (clamped to [0, 1]) and their
/// linear interpolation weights.
fn node_hats(x: f64, bins: usize) -> [(usize, f64); 2] {
    let x = x.clamp(0.0, 1.0) * (bins - 1) as f64;
    let lower = (x.floor() as usize).min(bins - 2);
    let upper_weight = x - lower as f64;
    [(lower, 1.0 - upper_weight), (lower + 1, upper_weight)]
}

/// Offset, in a lobe shape, of its elevation nodes' totals ([`CellTransfer::forward_shape`]).
pub const LOBE_AZIMUTH_TOTALS: usize = LOBE_AZIMUTH_BINS * 2 * LOBE_AZIMUTH_TERMS;

/// Offset, in a lobe shape, of its longitudinal nodes' totals.
pub const LOBE_LONGITUDINAL_TOTALS: usize = LOBE_AZIMUTH_TOTALS + LOBE_AZIMUTH_BINS;

/// Offset, in a lobe shape, of its longitudinal terms.
pub const LOBE_LONGITUDINAL_AT: usize = LOBE_LONGITUDINAL_TOTALS + LOBE_LONGITUDINAL_BINS;

/// Floats of one colour channel's lobe shape: per elevation node ([`LOBE_AZIMUTH_BINS`]) the
/// azimuthal terms `[cos Δφ, sin Δφ, cos 2Δφ, …]` ([`LOBE_AZIMUTH_TERMS`] pairs), then those
/// nodes' totals, then the longitudinal nodes' totals ([`LOBE_LONGITUDINAL_BINS`]), then per
/// longitudinal node the terms `[cos Δθ, sin Δθ, cos 2Δθ, …]` ([`LOBE_FOURIER_TERMS`] pairs).
pub const LOBE_CHANNEL_SHAPE_LEN: usize =
    LOBE_LONGITUDINAL_AT + LOBE_LONGITUDINAL_BINS * 2 * LOBE_FOURIER_TERMS;

/// Floats of one lobe shape ([`CellTransfer::forward_shape`]): a [`LOBE_CHANNEL_SHAPE_LEN`]
/// shape per colour channel, red, green, then blue. Each channel's connections are weighed at
/// that channel's colours: where a yarn is dark in a channel, that channel's light has met
/// fewer fibers and arrives from other directions (on the deep red silk satin, green and blue
/// light comes mostly off one reflection, red through chains of transmissions), and a shape
/// pooled over the channels, which the red light fills, held the silk's green and blue multiple
/// scattering about 50% bright (the median over the 100 hard configurations,
/// `docs/BENCHMARKS.md`).
pub const LOBE_SHAPE_LEN: usize = 3 * LOBE_CHANNEL_SHAPE_LEN;

/// Floats of one cell's fiber lobes as the GPU reads them (`lobes` in
/// `shaders/shared/fabric_data.wgsl`, written by [`CellTransfer::pack_lobes`]): the forward
/// strength as `sh_count(LOBE_SH_ORDER)` vec4s (RGB, 0), the reflected strength likewise, then
/// the forward shape's and the reflected shape's [`LOBE_SHAPE_LEN`] floats each, back to back,
/// padded with zeros to whole vec4s.
pub const LOBE_PACKED_FLOATS: usize = 8 * sh_count(LOBE_SH_ORDER) + (2 * LOBE_SHAPE_LEN).div_ceil(4) * 4;

/// Width, in `t · (ω × z)`, of the turn from −1 to 1 of [`toward_up`].
pub const TOWARD_UP_WIDTH: f64 = 0.1;

/// Which way about the unit fiber tangent t the fabric's up (+z) lies from direction ω: +1
/// where turning from ω's azimuth toward up is the positive sense about t, −1 where it is the
/// negative, and between them a linear ramp of `t · (ω × z)` over ±[`TOWARD_UP_WIDTH`] (0
/// where ω, t and z share a plane, and where t or ω is vertical). Light arrives at a fiber
/// turned from the light's azimuth toward the fabric's top, through the fibers above it (on
/// the silk satin backlit, a lobe made symmetric in azimuth lost a third of its light), so the
/// lobes hold the azimuth's odd part in this sense, which does not depend on the sign of t.
#[must_use]
pub fn toward_up(tangent: DVec3, dir: DVec3) -> f64 {
    (tangent.dot(dir.cross(DVec3::Z)) / TOWARD_UP_WIDTH).clamp(-1.0, 1.0)
}

/// Where light arrives from (ω1) against the light's own direction (ω0), both toward their
/// sources, in the frame of a fiber of unit tangent t: `Δθ = θ1 − θ0` of their angles to the
/// plane normal to t, and the angle Δφ turning from ω0's azimuth about t to ω1's, positive in
/// the positive sense about t (0 where either lies along t). A fiber's R and TT lobes keep the
/// light's angle to the fiber (a parallel neighbour sends light on at its own θ), so Δθ stays
/// small along a yarn, while R spreads the azimuth about the fiber and TT keeps it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FiberOffset {
    pub delta_theta: f64,
    pub delta_phi: f64,
    /// [`toward_up`] of the light's direction: the sense in which Δφ's odd part is kept.
    pub toward_up: f64,
    /// The light's elevation about the fiber ([`fiber_elevation`]: which
    /// [`LOBE_AZIMUTH_BINS`] nodes its azimuth goes to).
    pub elevation: f64,
    /// The light's `ω0·t`, the sine of its angle to the fiber (which
    /// [`LOBE_LONGITUDINAL_BINS`] nodes its Δθ goes to).
    pub along: f64,
}

impl FiberOffset {
    #[must_use]
    pub fn new(tangent: DVec3, to_light: DVec3, arrival: DVec3) -> Self {
        let angle = |w: DVec3| {
            let along = w.dot(tangent).clamp(-1.0, 1.0);
            (along.asin(), w - tangent * along)
        };
        let (theta0, across0) = angle(to_light);
        let (theta1, across1) = angle(arrival);
        let delta_phi = if across0.length() * across1.length() > 1e-12 {
            tangent.dot(across0.cross(across1)).atan2(across0.dot(across1))
        } else {
            0.0
        };
        Self {
            delta_theta: theta1 - theta0,
            delta_phi,
            toward_up: toward_up(tangent, to_light),
            elevation: fiber_elevation(tangent, to_light),
            along: to_light.dot(tangent).clamp(-1.0, 1.0),
        }
    }

    /// Adds `weight ×` this offset's shape terms (one channel of `CellTransfer::forward_shape`:
    /// [`LOBE_CHANNEL_SHAPE_LEN`] floats) to `shape`: `cos kΔφ` and `toward_up · sin kΔφ` to the two elevation nodes around the
    /// light's ([`elevation_hats`], each with its weight, and that weight to the node's total),
    /// and `cos kΔθ` and `sin kΔθ` likewise to the two longitudinal nodes around its `ω0·t`
    /// ([`longitudinal_hats`]).
    pub fn accumulate(&self, weight: f64, shape: &mut [f64]) {
        debug_assert_eq!(shape.len(), LOBE_CHANNEL_SHAPE_LEN);
        let (azimuth, rest) = shape.split_at_mut(LOBE_AZIMUTH_TOTALS);
        let (totals, rest) = rest.split_at_mut(LOBE_AZIMUTH_BINS);
        let (longitudinal_totals, longitudinal) = rest.split_at_mut(LOBE_LONGITUDINAL_BINS);
        for (node, hat) in elevation_hats(self.elevation) {
            let w = weight * hat;
            if w == 0.0 {
                continue;
            }
            totals[node] += w;
            let odd = w * self.toward_up;
            let terms = &mut azimuth[node * 2 * LOBE_AZIMUTH_TERMS..(node + 1) * 2 * LOBE_AZIMUTH_TERMS];
            for (k, pair) in terms.chunks_exact_mut(2).enumerate() {
                let (sk, ck) = ((k + 1) as f64 * self.delta_phi).sin_cos();
                pair[0] += w * ck;
                pair[1] += odd * sk;
            }
        }
        let (s1, c1) = self.delta_theta.sin_cos();
        for (node, hat) in longitudinal_hats(self.along) {
            let w = weight * hat;
            if w == 0.0 {
                continue;
            }
            longitudinal_totals[node] += w;
            let terms = &mut longitudinal[node * 2 * LOBE_FOURIER_TERMS..(node + 1) * 2 * LOBE_FOURIER_TERMS];
            let (mut sk, mut ck) = (s1, c1);
            for pair in terms.chunks_exact_mut(2) {
                pair[0] += w * ck;
                pair[1] += w * sk;
                (ck, sk) = (ck * c1 - sk * s1, sk * c1 + ck * s1);
            }
        }
    }
}

impl FiberOffset {
    /// [`Self::accumulate`] into both lobes' shapes (forward, then reflected: each
    /// [`LOBE_SHAPE_LEN`] floats), each colour channel of `weights[lobe]` into that channel's
    /// shape.
    pub fn accumulate_rgb(&self, weights: [Rgb; 2], shapes: &mut [Vec<f64>; 2]) {
        for (weight, shape) in weights.iter().zip(shapes.iter_mut()) {
            for (channel, part) in shape.chunks_exact_mut(LOBE_CHANNEL_SHAPE_LEN).enumerate() {
                if weight[channel] != 0.0 {
                    self.accumulate(weight[channel], part);
                }
            }
        }
    }
}

/// A light connection's SH over ω0, for the matrix (order L) and, with fiber lobes, for their
/// strengths ([`LOBE_SH_ORDER`]): one evaluation at the higher order serves both, since
/// [`sh_eval`]'s first (L+1)² values are order L's whatever the order asked for.
pub(crate) struct ConnectionSh {
    values: Vec<f64>,
    matrix_len: usize,
    order: usize,
}

impl ConnectionSh {
    pub(crate) fn new(order: usize, lobes: bool) -> Self {
        let order_evaluated = if lobes { LOBE_SH_ORDER.max(order) } else { order };
        Self {
            values: vec![0.0; sh_count(order_evaluated)],
            matrix_len: sh_count(order),
            order: order_evaluated,
        }
    }

    pub(crate) fn eval(&mut self, dir: DVec3) {
        sh_eval(self.order, dir, &mut self.values);
    }

    /// The (L+1)² values the matrix takes.
    pub(crate) fn matrix(&self) -> &[f64] {
        &self.values[..self.matrix_len]
    }

    /// The `sh_count(LOBE_SH_ORDER)` values a lobe's strength takes (only with lobes).
    pub(crate) fn lobe(&self) -> &[f64] {
        &self.values[..sh_count(LOBE_SH_ORDER).min(self.values.len())]
    }
}

impl CellTransfer {
    /// The transfer of a cell with no segments: no entries, no paths.
    #[must_use]
    pub fn empty() -> Self {
        Self {
            paths: 0,
            matrix: Vec::new(),
            std_error: Vec::new(),
            forward: Vec::new(),
            forward_cosine: [0.0; 3],
            reflected: Vec::new(),
            forward_shape: Vec::new(),
            reflected_shape: Vec::new(),
        }
    }

    /// Whether the cell carries its transfer as fiber lobes (its matrix is then zero).
    #[must_use]
    pub fn has_lobes(&self) -> bool {
        !self.forward.is_empty()
    }

    /// Whether the cell has lobes that carry light (a nonzero forward or reflected strength
    /// (0), each a sum of non-negative shares): the test that sends a segment to its lattice
    /// cells instead of its own transfer (`shading::multiple::segment_transfer`; WGSL
    /// `slot_keeps_lobes` reads the same f32 values).
    #[must_use]
    pub fn keeps_lobe_light(&self) -> bool {
        let lit = |v: &[[f32; 3]]| v.first().is_some_and(|c| c.iter().any(|&x| x != 0.0));
        lit(&self.forward) || lit(&self.reflected)
    }

    /// Writes the cell's lobes in the GPU's layout ([`LOBE_PACKED_FLOATS`] floats) into `out`:
    /// zeros for a cell without lobes.
    ///
    /// # Panics
    /// If `out` does not hold [`LOBE_PACKED_FLOATS`] floats.
    pub fn pack_lobes(&self, out: &mut [f32]) {
        assert_eq!(out.len(), LOBE_PACKED_FLOATS, "pack_lobes: {} floats", out.len());
        out.fill(0.0);
        if !self.has_lobes() {
            return;
        }
        let strengths = self.forward.iter().chain(&self.reflected);
        for (vec4, rgb) in out.chunks_exact_mut(4).zip(strengths) {
            vec4[..3].copy_from_slice(rgb);
        }
        let shapes = &mut out[8 * sh_count(LOBE_SH_ORDER)..];
        for (v, s) in shapes.iter_mut().zip(self.forward_shape.iter().chain(&self.reflected_shape)) {
            *v = *s;
        }
    }

    /// Whether the cell holds no matrix (it has no segments and transfers nothing).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.matrix.is_empty()
    }

    /// Entry `i` of the matrix (`j1 * n + j0`) in f64; zero for an empty cell.
    #[must_use]
    pub fn entry(&self, i: usize) -> Rgb {
        self.matrix.get(i).map_or(Rgb::ZERO, |v| glam::Vec3::from(*v).as_dvec3())
    }

    /// Row j1 of the matrix in f64 (`n` entries, zeros for an empty cell).
    pub fn row(&self, j1: usize, n: usize) -> impl Iterator<Item = Rgb> + '_ {
        (0..n).map(move |j0| self.entry(j1 * n + j0))
    }

    /// `c_T = A_C c_in`: the SH coefficients of T(·, ω1, C) as a function of ω1 for light with
    /// SH coefficients `c_in` (for a directional light from ω_d, `c_in = Y(ω_d)`).
    #[must_use]
    pub fn apply(&self, c_in: &[f64]) -> Vec<Rgb> {
        let n = c_in.len();
        debug_assert!(self.is_empty() || n * n == self.matrix.len());
        (0..n).map(|j1| self.row(j1, n).zip(c_in).map(|(a, c)| a * *c).sum()).collect()
    }
}

/// The IIRTF of every cell of a grid. Stored (serde) as it is held: f32 entries, empty cells
/// without matrices; loading checks every cell's size ([`StoredIirtf`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "StoredIirtf")]
pub struct Iirtf {
    pub sh_order: usize,
    pub light_domain: LightDomain,
    pub cells: Vec<CellTransfer>,
}

/// An overall noise figure: root-mean-square entry and standard error over all nonempty cells,
/// entries and channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IirtfNoise {
    pub rms_entry: f64,
    pub rms_std_error: f64,
}

impl Iirtf {
    #[must_use]
    pub fn noise(&self) -> IirtfNoise {
        let (mut v, mut e, mut count) = (0.0, 0.0, 0.0);
        let square = |x: &[f32; 3]| x.iter().map(|c| f64::from(*c).powi(2)).sum::<f64>();
        for cell in self.cells.iter().filter(|c| c.paths > 0) {
            for (a, s) in cell.matrix.iter().zip(&cell.std_error) {
                v += square(a);
                e += square(s);
                count += 3.0;
            }
        }
        let count: f64 = f64::max(count, 1.0);
        IirtfNoise { rms_entry: (v / count).sqrt(), rms_std_error: (e / count).sqrt() }
    }
}

/// An [`Iirtf`] as read from a file, before its cells' sizes are checked.
#[derive(serde::Deserialize)]
pub struct StoredIirtf {
    sh_order: usize,
    light_domain: LightDomain,
    cells: Vec<CellTransfer>,
}

impl TryFrom<StoredIirtf> for Iirtf {
    type Error = String;

    fn try_from(stored: StoredIirtf) -> Result<Self, String> {
        let n = (stored.sh_order + 1) * (stored.sh_order + 1);
        for (i, c) in stored.cells.iter().enumerate() {
            let expected = if c.paths == 0 { 0 } else { n * n };
            if c.matrix.len() != expected || c.std_error.len() != expected {
                return Err(format!(
                    "IIRTF cell {i} ({} paths) has {} entries and {} errors, expected {expected}",
                    c.paths,
                    c.matrix.len(),
                    c.std_error.len()
                ));
            }
            let lobe = sh_count(LOBE_SH_ORDER);
            let sizes = [c.forward.len(), c.reflected.len(), c.forward_shape.len(), c.reflected_shape.len()];
            if sizes != [0; 4] && (c.paths == 0 || sizes != [lobe, lobe, LOBE_SHAPE_LEN, LOBE_SHAPE_LEN]) {
                return Err(format!(
                    "IIRTF cell {i} ({} paths) has fiber lobes of {} forward, {} reflected coefficients \
                     and shapes of {} and {} terms, expected none or {lobe}, {lobe}, {LOBE_SHAPE_LEN} \
                     and {LOBE_SHAPE_LEN}",
                    c.paths, sizes[0], sizes[1], sizes[2], sizes[3]
                ));
            }
        }
        Ok(Self { sh_order: stored.sh_order, light_domain: stored.light_domain, cells: stored.cells })
    }
}

/// Tuning beyond [`BakeSettings`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IirtfOptions {
    pub light_domain: LightDomain,
    /// Which light transport the matrices hold (all of it in a bake).
    pub part: TransferPart,
    /// Walk as the colours say even where the colour-free walk would be taken
    /// ([`TransferSampler::with_colour_aware_walk`]; tests and diagnostics: a bake never sets it).
    pub colour_aware_walk: bool,
}

/// A part of the transfer, for measuring what the SH transfer holds well (`shading::budget`):
/// the light connections of the same paths split three ways, so the parts sum to the whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TransferPart {
    /// Every light connection (what a bake stores).
    #[default]
    All,
    /// Only light transmitted by the first fiber a path meets: the connection at its first
    /// event drawn from that fiber's TT lobe. Light that went through one neighbouring fiber
    /// almost undeflected, peaked around the light's direction.
    FirstTransmission,
    /// Only light reflected by the first fiber a path meets (its first event's connection
    /// drawn from the R lobe; a Lambertian surface's counts here too): a cone about that
    /// fiber's axis, as narrow as the R lobe.
    FirstReflection,
    /// The connections of every later event: light scattered two or more times.
    Later,
    /// Forward chains: light transmitted by every fiber on its way, the TT lobe's share of
    /// each event's scattering (the path's continuations and its light connection alike), so
    /// that it and [`Self::AfterReflection`] split every connection's weight exactly. Light
    /// that stays peaked around the light's direction however many fibers it crosses.
    ForwardChains,
    /// What [`Self::ForwardChains`] leaves: light reflected at least once on its way (a
    /// Lambertian surface's scattering counts here).
    AfterReflection,
}

impl TransferPart {
    /// Whether a light connection at `event` (1 = a path's first fiber event), drawn from
    /// `lobe` (`None`: not a fiber), belongs to this part.
    fn holds(self, event: u32, lobe: Option<Lobe>) -> bool {
        match self {
            // The chain parts split every connection's weight instead ([`Self::share`]).
            Self::All | Self::ForwardChains | Self::AfterReflection => true,
            Self::FirstTransmission => event == 1 && lobe == Some(Lobe::Tt),
            Self::FirstReflection => event == 1 && lobe != Some(Lobe::Tt),
            Self::Later => event > 1,
        }
    }

    /// The share of a connection's weight this part keeps, given the whole weight `all` and
    /// its forward-chain share `forward` (only the two chain parts split a weight).
    pub(crate) fn share(self, all: Rgb, forward: Rgb) -> Rgb {
        match self {
            Self::ForwardChains => forward,
            Self::AfterReflection => all - forward,
            _ => all,
        }
    }
}

/// One path's sample of T: the radiance arriving at μ_k from −ω1 (`view`), split by the
/// light directions ω0 it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct TransferSample {
    /// ω1: the radiance arrives at μ_k from −ω1.
    pub view: DVec3,
    /// `(ω0, T-contribution / (p(ω0) p(ω1)))`: one entry per fiber event of the path whose
    /// light sample ω0 lies in the light domain and reaches the fiber; the path's estimate of
    /// `∫ T(ω0, ω1) f(ω0) dω0 / p(ω1)` for any f is `Σ weight · f(ω0)`.
    pub lights: Vec<(DVec3, Rgb)>,
    /// Per entry of `lights`, the forward chains' share of its weight before the sampler's
    /// part is taken ([`TransferPart::ForwardChains`]): all of it when the connection and every
    /// continuation before it took a fiber's TT lobe ([`ColourFreeSample::forward`]), none
    /// otherwise. The walk chooses lobes as a one-sample estimator, so the expected share is
    /// the TT lobe's share of every event's scattering on the way.
    pub forward: Vec<Rgb>,
    pub segment: u32,
}

/// Draws [`TransferSample`]s: a fabric tiled over the plane (no ground, no lights).
pub struct TransferSampler {
    scene: FiberScene,
    /// Material of each yarn (indexed by `Hit::yarn`).
    yarn_materials: Vec<Material>,
    /// Material slot of each yarn (`Yarn::material`), for the colour-free walk.
    yarn_slots: Vec<u32>,
    /// Material slots (one above the largest of `yarn_slots`).
    slot_count: usize,
    /// Whether [`Self::sample`] takes the colour-free walk ([`walks_colour_free`]).
    walks_colour_free: bool,
    midpoints: Vec<DVec3>,
    /// Unit tangent of each segment (the fiber frame [`FiberOffset`] is taken in).
    tangents: Vec<DVec3>,
    /// Half the length and the radius of each segment (where [`Self::exposed_start`] puts
    /// a path's start on it).
    half_lengths: Vec<f64>,
    radii: Vec<f64>,
    fibers: Vec<u32>,
    light_domain: LightDomain,
    part: TransferPart,
    /// Whether paths start at points of the cell's fibers an eye sees ([`Self::exposed_start`])
    /// rather than at segment midpoints (`BakeSettings::exposed_starts`).
    exposed_starts: bool,
    /// Light samples drawn at each fiber event (`BakeSettings::iirtf_light_samples`), each
    /// weighted by its share.
    light_samples: u32,
}

impl TransferSampler {
    /// `yarn_materials[y]` is the material of yarn y.
    pub fn new(
        exemplar: &Exemplar,
        yarn_materials: &[Material],
        light_domain: LightDomain,
    ) -> Result<Self, IirtfError> {
        if yarn_materials.len() < exemplar.yarns.len() {
            return Err(IirtfError::MaterialCount {
                yarns: exemplar.yarns.len(),
                materials: yarn_materials.len(),
            });
        }
        let scene = FiberScene::new(exemplar, Extent::Unbounded)?;
        let offset = scene.tile_offset(scene.central_tile());
        let segments = exemplar.segments();
        let midpoints = segments.iter().map(|s| s.midpoint().as_dvec3() + offset).collect();
        let fiber_ids = segments.iter().map(|s| s.fiber).collect();
        let tangents = segments.iter().map(|s| s.tangent().as_dvec3().normalize_or_zero()).collect();
        Ok(Self {
            scene,
            tangents,
            half_lengths: segments.iter().map(|s| 0.5 * f64::from(s.length())).collect(),
            radii: segments.iter().map(|s| f64::from(s.radius)).collect(),
            exposed_starts: false,
            yarn_materials: yarn_materials.to_vec(),
            yarn_slots: exemplar.yarns.iter().map(|y| y.material).collect(),
            slot_count: exemplar.yarns.iter().map(|y| y.material as usize + 1).max().unwrap_or(0),
            walks_colour_free: walks_colour_free(&yarn_materials[..exemplar.yarns.len()]),
            midpoints,
            fibers: fiber_ids,
            light_domain,
            part: TransferPart::All,
            light_samples: 1,
        })
    }

    /// The sampler with [`Self::sample`] keeping only the light connections of `part`.
    #[must_use]
    pub fn with_part(self, part: TransferPart) -> Self {
        Self { part, ..self }
    }

    /// The sampler with [`Self::sample`] walking as the colours say (the walk it takes for
    /// yarns whiter than [`COLOUR_FREE_MAX_TAU`]) when `colour_aware` is true, for any colours:
    /// another estimator of the same transfer, to check the two against each other.
    #[must_use]
    pub fn with_colour_aware_walk(self, colour_aware: bool) -> Self {
        Self { walks_colour_free: self.walks_colour_free && !colour_aware, ..self }
    }

    /// The sampler with paths starting where an eye sees the cell's fibers
    /// ([`Self::exposed_start`]) when `exposed` is true, at segment midpoints (the paper)
    /// otherwise.
    #[must_use]
    pub fn with_exposed_starts(self, exposed: bool) -> Self {
        Self { exposed_starts: exposed, ..self }
    }

    /// The sampler drawing `count` light samples at each fiber event
    /// (`BakeSettings::iirtf_light_samples`; at least 1), spread over the light's uniforms
    /// by [`spread_light_uniforms`], each connection weighted by `1 / count`.
    #[must_use]
    pub fn with_light_samples(self, count: usize) -> Self {
        Self { light_samples: u32::try_from(count.max(1)).unwrap_or(u32::MAX), ..self }
    }

    /// Unit tangent of segment k.
    #[must_use]
    pub fn tangent(&self, k: u32) -> DVec3 {
        self.tangents[k as usize]
    }

    /// World position (central copy) of segment k's midpoint.
    #[must_use]
    pub fn midpoint(&self, k: u32) -> DVec3 {
        self.midpoints[k as usize]
    }

    /// A path's start: a segment k of the cell, a point x on it, ω1 uniformly on the sphere,
    /// and the first fiber hit from x toward ω1 (k's own fiber ignored), from the path's
    /// [`path_strata`] point `u` (dimensions 0–2; the exposed start draws from `rng`). x is
    /// μ_k, k drawn uniformly, or with exposed starts a point an eye sees
    /// ([`Self::exposed_start`]).
    fn first_hit(
        &self,
        cell_segments: &[u32],
        u: &[f64; STRATA_DIMS],
        rng: &mut rand_pcg::Pcg64Mcg,
    ) -> (u32, DVec3, Option<crate::raycast::Hit>) {
        let index = ((u[0] * cell_segments.len() as f64) as usize).min(cell_segments.len() - 1);
        let (k, origin) = self
            .exposed_starts
            .then(|| self.exposed_start(cell_segments, index, rng))
            .flatten()
            .unwrap_or_else(|| {
                let k = cell_segments[index];
                (k, self.midpoints[k as usize])
            });
        let view = uniform_sphere(u[1], u[2]);
        let hit = self.scene.closest_hit(
            origin.as_vec3(),
            view.as_vec3(),
            f32::INFINITY,
            Some(self.fibers[k as usize]),
        );
        (k, view, hit)
    }

    /// A point of the cell's fibers that an eye sees, and its segment: an eye direction e
    /// uniform over the hemisphere the light domain lights (the whole sphere for
    /// [`LightDomain::Sphere`]), a segment of the cell (the stratified `first` on the first
    /// try, uniform after it) kept with probability `|e × t|` (its area as e sees it, per unit
    /// length), a point uniform over that area on the side of the fiber facing e, kept when
    /// nothing lies between it and the eye. Kept points are distributed as the eye's hits on
    /// the cell's fibers from directions uniform over the hemisphere: the exposed fibers, and
    /// on them the sides that face out, which are the ones the method shades (the IIRTF at a
    /// segment's midpoint on the axis averages in the parts under neighbouring fibers and
    /// crossing yarns, which are darker). `None` after [`EXPOSED_START_TRIES`] tries (a cell no
    /// eye sees): the caller starts at the midpoint.
    pub(crate) fn exposed_start(
        &self,
        cell_segments: &[u32],
        first: usize,
        rng: &mut rand_pcg::Pcg64Mcg,
    ) -> Option<(u32, DVec3)> {
        for attempt in 0..EXPOSED_START_TRIES {
            let index = if attempt == 0 {
                first
            } else {
                ((rng.random::<f64>() * cell_segments.len() as f64) as usize).min(cell_segments.len() - 1)
            };
            let k = cell_segments[index] as usize;
            let mut eye = uniform_sphere(rng.random(), rng.random());
            if self.light_domain == LightDomain::UpperHemisphere {
                eye.z = eye.z.abs();
            }
            let t = self.tangents[k];
            let across = eye - eye.dot(t) * t;
            let sin_et = across.length();
            if rng.random::<f64>() >= sin_et {
                continue;
            }
            let toward_eye = across / sin_et;
            let side = t.cross(toward_eye);
            let (along, lateral) = (2.0 * rng.random::<f64>() - 1.0, 2.0 * rng.random::<f64>() - 1.0);
            let out = lateral * side + (1.0 - lateral * lateral).max(0.0).sqrt() * toward_eye;
            let point = self.midpoints[k] + along * self.half_lengths[k] * t + self.radii[k] * out;
            if !self.scene.any_hit_f64(point, eye, f64::INFINITY, Some(self.fibers[k])) {
                return Some((cell_segments[index], point));
            }
        }
        None
    }

    /// Whether an eye sees segment `k` ([`Self::exposed_start`] on `k` alone, up to
    /// [`EYE_SEES_TRIES`] tries, drawn from `stream`): a segment cell's transfer is baked only
    /// for a segment that can be shaded; a buried one is shaded, if ever, by the lattice's
    /// cells. A segment an eye sees over a fraction f of its area fails all tries with
    /// probability about `(1 − 0.78 f)^64` (under 1% at f = 0.09).
    pub(crate) fn eye_sees(&self, k: u32, stream: u64) -> bool {
        let mut rng = pixel_rng(stream ^ EYE_SEES_STREAM, 0);
        (0..EYE_SEES_TRIES / EXPOSED_START_TRIES).any(|_| self.exposed_start(&[k], 0, &mut rng).is_some())
    }

    /// Whether light from `to_light` counts (the light domain).
    fn in_domain(&self, to_light: DVec3) -> bool {
        match self.light_domain {
            LightDomain::UpperHemisphere => to_light.z > 0.0,
            LightDomain::Sphere => true,
        }
    }

    /// Path `path` of a cell with segments `cell_segments` (nonempty), from stream `stream`:
    /// the colour-free walk ([`Self::sample_colour_free`]) weighed exactly at the sampler's own
    /// materials' colours.
    ///
    /// The path leaves μ_k toward a uniform ω1 (pdf 1/4π, the segment's own fiber ignored on
    /// the first ray) and walks the fabric (each continuation's lobe chosen and sampled without
    /// the colours, Russian roulette on the colour-free weight from the fourth event). At every
    /// fiber event it draws its own light direction ω0 from that fiber's scattering function
    /// (lobe widths only, the density the event weighs light with) and casts a shadow ray: the
    /// event's contribution is `throughput · S cos θ0 / p(ω0)` where the ray escapes and ω0 is
    /// in the domain. The paper instead draws one uniform ω0 per path; the fiber lobes are
    /// narrow, so a uniform ω0 rarely lands in them and the matrices were noisy (a draft bake's
    /// image mean moved by ±8% between seeds).
    ///
    /// Why the colour-free walk: the recolouring basis (`bake::recolour`) walks the same paths
    /// and differentiates them in the colours, so a bake and a live recolouring at the same
    /// colours differ by the basis's approximation alone, not by two draws of the transfer's
    /// noise (which moved a recoloured picture's mean by up to 6% against its rebake when the
    /// bake walked with its colours). Yarns whiter than [`COLOUR_FREE_MAX_TAU`] take a walk
    /// that follows their colours instead ([`walks_colour_free`]), whose weights stay bounded.
    /// With [`Self::with_part`], only that part's connections
    /// are kept (the same paths and random numbers either way).
    #[must_use]
    pub fn sample(&self, cell_segments: &[u32], stream: u64, path: u64) -> TransferSample {
        if !self.walks_colour_free {
            return self.sample_colour_aware(cell_segments, stream, path);
        }
        let mut walk = ColourFreeSample::default();
        self.sample_colour_free(cell_segments, stream, path, self.slot_count, &mut walk);
        let mut lights = Vec::with_capacity(walk.lights.len());
        let mut forward_shares = Vec::with_capacity(walk.lights.len());
        for (((&(to_light, _, _), &all), &(event, lobe)), &forward) in
            walk.lights.iter().zip(&walk.own).zip(&walk.event_lobe).zip(&walk.forward)
        {
            if self.part.holds(event, lobe) {
                let share = if forward { all } else { Rgb::ZERO };
                lights.push((to_light, self.part.share(all, share)));
                forward_shares.push(share);
            }
        }
        TransferSample { view: walk.view, lights, forward: forward_shares, segment: walk.segment }
    }

    /// [`Self::sample`] for yarns too white for the colour-free walk ([`COLOUR_FREE_MAX_TAU`]):
    /// the walk follows the colours, as the path tracer does (each continuation's lobe chosen
    /// by its share of the scattering at the yarn's colours, Russian roulette by throughput),
    /// and the forward chains' share is split off every connection exactly (the TT lobe's share
    /// of each event's scattering on the way).
    fn sample_colour_aware(&self, cell_segments: &[u32], stream: u64, path: u64) -> TransferSample {
        let strata = path_strata(stream, path);
        let mut rng = pixel_rng(stream, path);
        let (k, view, mut hit) = self.first_hit(cell_segments, &strata, &mut rng);
        let inv_p1 = 4.0 * std::f64::consts::PI;
        let mut lights = Vec::new();
        let mut forward_shares = Vec::new();
        let fibers = &self.scene;
        let mut dir = view;
        let mut throughput = Rgb::ONE;
        // The TT lobe's share of `throughput` (TransferPart::ForwardChains).
        let mut forward = Rgb::ONE;
        for event in 1..=MAX_DEPTH {
            let Some(h) = hit else { break };
            let (position, t, n) = (h.position.as_dvec3(), h.tangent.as_dvec3(), h.normal.as_dvec3());
            let material = &self.yarn_materials[h.yarn as usize];
            let wo = -dir;
            let first_light = light_uniforms(event, &strata, &mut rng);
            for m in 0..self.light_samples {
                let u_light = spread_light_uniforms(first_light, m);
                let kept = self.part == TransferPart::All || {
                    let lobe = match material {
                        Material::Fiber(f) if event == 1 => f.sampled_lobe(t, wo, u_light),
                        _ => None,
                    };
                    self.part.holds(event, lobe)
                };
                if kept
                    && let Some((to_light, pdf)) = material.sample(t, n, wo, u_light)
                    && self.in_domain(to_light)
                {
                    let f = material.eval_cos(t, n, to_light, wo);
                    if f != Rgb::ZERO
                        && !fibers.any_hit(
                            position.as_vec3(),
                            to_light.as_vec3(),
                            f32::INFINITY,
                            Some(h.fiber),
                        )
                    {
                        let scale = inv_p1 / (pdf * f64::from(self.light_samples));
                        let share = forward * material.eval_cos_tt(t, to_light, wo) * scale;
                        lights.push((to_light, self.part.share(throughput * f * scale, share)));
                        forward_shares.push(share);
                    }
                }
            }
            let Some((wi, pdf)) = material.sample(t, n, wo, [rng.random(), rng.random(), rng.random()])
            else {
                break;
            };
            let f = material.eval_cos(t, n, wi, wo);
            if f == Rgb::ZERO || !(pdf > 0.0 && pdf.is_finite()) {
                break;
            }
            throughput *= f / pdf;
            forward *= material.eval_cos_tt(t, wi, wo) / pdf;
            dir = wi;
            hit = fibers.closest_hit(position.as_vec3(), wi.as_vec3(), f32::INFINITY, Some(h.fiber));
            let before = throughput.max_element();
            if !russian_roulette(event, &mut throughput, &mut rng) {
                break;
            }
            // Roulette divides the whole throughput by its survival; the share goes with it.
            forward *= throughput.max_element() / before;
        }
        TransferSample { view, lights, forward: forward_shares, segment: k }
    }
}

/// One path of the colour-free walk ([`TransferSampler::sample_colour_free`]), its buffers
/// reused from path to path.
#[derive(Debug, Clone, Default)]
pub struct ColourFreeSample {
    /// ω1, as in [`TransferSample::view`].
    pub view: DVec3,
    /// Per light connection: ω0, its colour-free weight (every event's colour-free weight, R
    /// events at C_R = [`COLOUR_FREE_C_R`], over p(ω0) p(ω1) and Russian roulette's survival)
    /// and the number K of TT events it carries (this event's included).
    pub lights: Vec<(DVec3, f64, u32)>,
    /// Per light connection, per material slot (`slots` wide): TT events in that slot.
    pub tt_events: Vec<u32>,
    /// Per light connection, per material slot: `Σ (1 − m) / (C_R + (1 − C_R) m)` over its R
    /// events in that slot at C_R = [`COLOUR_FREE_C_R`], the derivative of the log weight in C_R.
    pub r_log_derivative: Vec<f64>,
    /// Per light connection, whether it is a forward chain ([`TransferPart::ForwardChains`]):
    /// the connection and every continuation before it sampled the TT lobe of a transmissive
    /// material (a fiber; a Lambertian surface reports [`Lobe::Tt`] but never counts). The walk
    /// chooses lobes as a one-sample estimator (a chosen lobe's weight is over its choice
    /// probability), so the expected weight of the connections flagged here is the forward
    /// share [`TransferSampler::sample`] splits off exactly, at any colours: a forward chain's
    /// colour factors are its τ's alone.
    pub forward: Vec<bool>,
    /// Per light connection, its weight at the sampler's own materials' colours, exactly: the
    /// colour-free weight times τ per TT event and `(C_R + (1 − C_R) m) / (C_R,0 + (1 − C_R,0) m)`
    /// per R event, each at its yarn's colours (what [`TransferSampler::sample`] keeps).
    pub own: Vec<Rgb>,
    /// Per light connection, the event it was made at (1 = the path's first fiber event) and
    /// the lobe its light direction was drawn from (`None` on a Lambertian surface), what
    /// [`TransferPart`] sorts connections by.
    pub event_lobe: Vec<(u32, Option<Lobe>)>,
    /// The segment k the path starts at (as [`TransferSample::segment`]): its tangent is the
    /// fiber frame of the lobes' shapes ([`FiberOffset`]).
    pub segment: u32,
    /// Material slots (the width of the two arrays above).
    pub slots: usize,
}

impl TransferSampler {
    /// [`Self::sample`] with every colour left out of the walk (`bake::recolour`): lobes are
    /// chosen and sampled by [`Material::sample_colour_free`] (lobe widths and geometry only),
    /// Russian roulette follows the colour-free weight at TT factor
    /// [`COLOUR_FREE_ROULETTE_ALBEDO`], and each light connection records its colour-free
    /// weight, its event counts and whether it is a forward chain, from which the transfer at
    /// any colours, split as [`BakeSettings::fiber_lobes`] splits it, follows by multiplying
    /// in the colour factors. The walk does not depend on the materials' colours
    /// (tested), so differentiating it in the colours is unbiased. `slots` is the number of
    /// material slots (every yarn's slot is below it, slots no yarn uses included), the width
    /// of the per-slot counts in `out`.
    pub fn sample_colour_free(
        &self,
        cell_segments: &[u32],
        stream: u64,
        path: u64,
        slots: usize,
        out: &mut ColourFreeSample,
    ) {
        debug_assert!(self.yarn_slots.iter().all(|&s| (s as usize) < slots));
        out.lights.clear();
        out.tt_events.clear();
        out.r_log_derivative.clear();
        out.forward.clear();
        out.own.clear();
        out.event_lobe.clear();
        out.slots = slots;
        let strata = path_strata(stream, path);
        let mut rng = pixel_rng(stream, path);
        let (segment, view, mut hit) = self.first_hit(cell_segments, &strata, &mut rng);
        out.view = view;
        out.segment = segment;
        let inv_p1 = 4.0 * std::f64::consts::PI;
        // Each of an event's light samples carries this share of its connection.
        let share = 1.0 / f64::from(self.light_samples);
        let fibers = &self.scene;
        let mut dir = view;
        let mut weight = 1.0;
        let mut tt_total = 0_u32;
        let mut tt_events = vec![0_u32; slots];
        let mut r_log = vec![0.0_f64; slots];
        // The weight's colour factors at the sampler's own colours (ColourFreeSample::own).
        let mut own = Rgb::ONE;
        // Whether every continuation so far was a fiber's TT lobe (ColourFreeSample::forward).
        let mut chain = true;
        let r0 = COLOUR_FREE_C_R;
        // An R event's colour factor at the yarn's C_R over the walk's.
        let r_ratio =
            |c_r: Rgb, schlick: f64| (c_r + (Rgb::ONE - c_r) * schlick) / (r0 + (1.0 - r0) * schlick);
        for event in 1..=MAX_DEPTH {
            let Some(h) = hit else { break };
            let (position, t, n) = (h.position.as_dvec3(), h.tangent.as_dvec3(), h.normal.as_dvec3());
            let material = &self.yarn_materials[h.yarn as usize];
            let slot = self.yarn_slots[h.yarn as usize] as usize;
            // The colours at which `own` weighs the walk (never read by the walk itself).
            let (tau, c_r) = material.colour_variables();
            let wo = -dir;
            let first_light = light_uniforms(event, &strata, &mut rng);
            for m in 0..self.light_samples {
                let u_light = spread_light_uniforms(first_light, m);
                if let Some(e) = material.sample_colour_free(t, n, wo, u_light)
                    && self.in_domain(e.dir)
                    && !fibers.any_hit(position.as_vec3(), e.dir.as_vec3(), f32::INFINITY, Some(h.fiber))
                {
                    let at = out.lights.len() * slots;
                    out.tt_events.extend_from_slice(&tt_events);
                    out.r_log_derivative.extend_from_slice(&r_log);
                    let (light_weight, colours) = match e.lobe {
                        Lobe::Tt => {
                            out.tt_events[at + slot] += 1;
                            (weight * e.weight * inv_p1 * share, tau)
                        }
                        Lobe::R => {
                            let rho = r0 + (1.0 - r0) * e.schlick;
                            out.r_log_derivative[at + slot] += (1.0 - e.schlick) / rho;
                            (weight * e.weight * rho * inv_p1 * share, r_ratio(c_r, e.schlick))
                        }
                    };
                    out.lights.push((e.dir, light_weight, tt_total + u32::from(e.lobe == Lobe::Tt)));
                    out.forward.push(chain && e.lobe == Lobe::Tt && material.is_transmissive());
                    out.own.push(own * colours * light_weight);
                    out.event_lobe.push((event, material.is_transmissive().then_some(e.lobe)));
                }
            }
            let Some(e) = material.sample_colour_free(t, n, wo, [rng.random(), rng.random(), rng.random()])
            else {
                break;
            };
            chain &= e.lobe == Lobe::Tt && material.is_transmissive();
            match e.lobe {
                Lobe::Tt => {
                    weight *= e.weight;
                    own *= tau;
                    tt_total += 1;
                    tt_events[slot] += 1;
                }
                Lobe::R => {
                    let rho = r0 + (1.0 - r0) * e.schlick;
                    weight *= e.weight * rho;
                    own *= r_ratio(c_r, e.schlick);
                    r_log[slot] += (1.0 - e.schlick) / rho;
                }
            }
            dir = e.dir;
            hit = fibers.closest_hit(position.as_vec3(), e.dir.as_vec3(), f32::INFINITY, Some(h.fiber));
            // Roulette on the weight at TT factor COLOUR_FREE_ROULETTE_ALBEDO: never on the colours.
            let sampled = weight * COLOUR_FREE_ROULETTE_ALBEDO.powi(tt_total.min(i32::MAX as u32) as i32);
            if !(sampled > 0.0 && sampled.is_finite()) {
                break;
            }
            let mut roulette = Rgb::splat(sampled);
            if !russian_roulette(event, &mut roulette, &mut rng) {
                break;
            }
            weight *= roulette.x / sampled;
        }
    }
}

/// The largest TT factor τ = (1 − C_R) C_TT for which [`TransferSampler::sample`] takes the
/// colour-free walk: the roulette's own factor, [`COLOUR_FREE_ROULETTE_ALBEDO`], the whitest
/// yarn the walk is made for. The walk chooses R with probability at least 0.1, so a TT event's
/// weight at the yarn's colours is about `τ / 0.9` of its survival's: up to 1.06 at this τ,
/// where a path's escape keeps its length in check, while at τ = 1 (a unit-albedo furnace, whose
/// paths run to hundreds of events) the weights grew geometrically and came back as pixels 3.5
/// times the exact answer.
pub const COLOUR_FREE_MAX_TAU: f64 = COLOUR_FREE_ROULETTE_ALBEDO;

/// Whether a bake of these yarn materials walks the colour-free paths the recolouring basis
/// differentiates (every yarn's τ at most [`COLOUR_FREE_MAX_TAU`] in every channel: every
/// preset) or, for whiter yarns, a walk that follows the colours (another estimator of the
/// same transfer).
#[must_use]
pub fn walks_colour_free(yarn_materials: &[Material]) -> bool {
    yarn_materials.iter().all(|m| m.colour_variables().0.max_element() <= COLOUR_FREE_MAX_TAU)
}

/// A uniform direction on the unit sphere from two uniforms.
#[must_use]
pub fn uniform_sphere(u0: f64, u1: f64) -> DVec3 {
    let z = 1.0 - 2.0 * u0;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (2.0 * std::f64::consts::PI * u1).sin_cos();
    DVec3::new(r * c, r * s, z)
}

/// Dimensions of a path's stratified start ([`path_strata`]).
pub const STRATA_DIMS: usize = 6;

/// The additive recurrences of a path's stratified start, one Roberts sequence per group of
/// dimensions that is integrated together: the segment (R_1, the golden ratio), the direction
/// ω1 (R_2) and the first light sample (R_3). `α_i = g^−i`, g the positive root of
/// `x^(d+1) = x + 1` for R_d (checked by a test). Each group's own projection is as even as
/// its sequence makes it (a single R_6 spreads one dimension less evenly than these).
const STRATA_STEPS: [f64; STRATA_DIMS] = [
    0.618_033_988_749_894_8,
    0.754_877_666_246_692_7,
    0.569_840_290_998_053_2,
    0.819_172_513_396_164_4,
    0.671_043_606_703_789_2,
    0.549_700_477_901_970_2,
];

/// Path `path`'s point of its cell's stratified start: the [`STRATA_STEPS`] sequences shifted
/// by a random vector drawn once per cell (Cranley–Patterson rotation). Dimension 0 picks the
/// segment, 1–2 the direction ω1, 3–5 the first event's light sample. Each point is uniform on
/// the unit cube (the shift is), so every path's estimate keeps its expectation, while a
/// cell's paths cover segments, directions and first light samples evenly instead of clumping
/// as independent draws do, and the per-cell noise falls (seed to seed, the default scene's
/// multiple scattering at interactive spread ±3.2 points instead of ±4.8; docs/BENCHMARKS.md).
#[must_use]
pub fn path_strata(stream: u64, path: u64) -> [f64; STRATA_DIMS] {
    let mut shift = pixel_rng(stream, u64::MAX);
    std::array::from_fn(|i| {
        let v = (shift.random::<f64>() + (path as f64 * STRATA_STEPS[i]).fract()).fract();
        // fract of a sum of two numbers in [0, 1) can round to 1.0.
        if v < 1.0 { v } else { 0.0 }
    })
}

/// The uniforms of the light sample at a path's `event` (1 = its first fiber event): the
/// first event's from its stratified start ([`path_strata`], dimensions 3–5), later ones from
/// the path's generator.
fn light_uniforms(event: u32, strata: &[f64; STRATA_DIMS], rng: &mut rand_pcg::Pcg64Mcg) -> [f64; 3] {
    if event == 1 { [strata[3], strata[4], strata[5]] } else { [rng.random(), rng.random(), rng.random()] }
}

/// The uniforms of an event's light sample `m` of several
/// ([`TransferSampler::with_light_samples`]): sample 0's ([`light_uniforms`]) moved by `m` steps
/// of the Roberts sequence R_3 (the first light sample's strata steps), modulo 1. Each is uniform
/// on the unit cube as sample 0 is, so each connection keeps its expectation, and an event's
/// samples cover the lobe choice and the lobe's angles evenly instead of clumping.
fn spread_light_uniforms(first: [f64; 3], m: u32) -> [f64; 3] {
    if m == 0 {
        return first;
    }
    std::array::from_fn(|i| {
        let v = (first[i] + f64::from(m) * STRATA_STEPS[3 + i]).fract();
        if v < 1.0 { v } else { 0.0 }
    })
}

/// The random stream of a cell's paths.
#[must_use]
pub fn cell_stream(seed: u64, cell: u32) -> u64 {
    seed ^ (u64::from(cell) + 1).wrapping_mul(0xD1B5_4A32_D192_ED03)
}

/// Paths between cancellation checks and progress reports.
pub(crate) const CHECK_EVERY: usize = 256;

/// Bakes the IIRTF of every cell of `grid` with `settings.iirtf_paths_per_cell` paths per
/// nonempty cell, `settings.sh_order` and `settings.seed`; see the module docs.
pub fn bake_iirtf(
    exemplar: &Exemplar,
    yarn_materials: &[Material],
    grid: &CellGrid,
    settings: &BakeSettings,
    options: &IirtfOptions,
    cancel: &Cancel,
    progress: Progress<'_>,
) -> Result<Iirtf, IirtfError> {
    bake_iirtf_cells(
        exemplar,
        yarn_materials,
        grid,
        settings,
        options,
        0..grid.cell_count(),
        cancel,
        progress,
    )
    .map(|cells| Iirtf { sh_order: settings.sh_order, light_domain: options.light_domain, cells })
}

/// Pools every segment cell's matrix with those of the segments of the same yarn around it:
/// each seen segment takes `Σ w_j M_j / Σ w_j` over the seen segments j of its yarn whose
/// midpoints lie within `radius_cm` of its own (across the period of a periodic exemplar),
/// `w_j = paths_j (1 − d²/r²)`, among those whose matrix holds the same light (all of it, or
/// the reflected part where their lattice cell keeps lobes). A segment's own paths estimate
/// its `(L+1)⁴` entries with the noise of a few dozen paths, which a view shows as grain that
/// does not average away; its neighbours lie on the same side of the yarn and share its
/// transfer, so pooling them trades that noise for a blur far finer than a lattice cell.
pub fn pool_segment_cells(exemplar: &Exemplar, grid: &CellGrid, cells: &mut [CellTransfer], radius_cm: f64) {
    let first = grid.lattice_cell_count();
    if cells.len() <= first || radius_cm.is_nan() || radius_cm <= 0.0 {
        return;
    }
    let segments = exemplar.segments();
    let period = grid.region_size_cm().truncate();
    let periodic = grid.is_periodic();
    let origin = grid.origin_cm().truncate();
    // Hash cells at least `radius_cm` wide, a whole number of them across the period.
    let counts = if periodic {
        [(period.x / radius_cm).floor().max(1.0) as i64, (period.y / radius_cm).floor().max(1.0) as i64]
    } else {
        [i64::MAX, i64::MAX]
    };
    let side = if periodic {
        glam::DVec2::new(period.x / counts[0] as f64, period.y / counts[1] as f64)
    } else {
        glam::DVec2::splat(radius_cm)
    };
    let wrap = |v: f64, p: f64| if periodic { v.rem_euclid(p) } else { v };
    let position = |k: usize| {
        let m = segments[k].midpoint().as_dvec3();
        DVec3::new(wrap(m.x - origin.x, period.x), wrap(m.y - origin.y, period.y), m.z)
    };
    let holds_reflected = |k: usize| {
        cells.get(grid.cell_of_segment(k as u32) as usize).is_some_and(CellTransfer::keeps_lobe_light)
    };
    let seen: Vec<usize> =
        (0..segments.len()).filter(|&k| cells.get(first + k).is_some_and(|c| c.paths > 0)).collect();
    let mut buckets: std::collections::HashMap<(i64, i64, u32, bool), Vec<usize>> =
        std::collections::HashMap::new();
    let bucket_of = |p: DVec3| ((p.x / side.x).floor() as i64, (p.y / side.y).floor() as i64);
    for &k in &seen {
        let (bx, by) = bucket_of(position(k));
        buckets.entry((bx, by, segments[k].yarn, holds_reflected(k))).or_default().push(k);
    }
    let n = cells[first + seen.first().copied().unwrap_or(0)].matrix.len();
    let cells_read: &[CellTransfer] = cells;
    let pooled: Vec<(usize, Vec<[f32; 3]>)> =
        seen.par_iter()
            .map(|&k| {
                let p = position(k);
                let (bx, by) = bucket_of(p);
                let key = (segments[k].yarn, holds_reflected(k));
                // The 3x3 hash cells around p, each once (across a period of fewer than three
                // cells, neighbours' offsets wrap onto the same cell).
                let mut around: Vec<(i64, i64)> =
                    (-1..=1_i64)
                        .flat_map(|dx| (-1..=1_i64).map(move |dy| (bx + dx, by + dy)))
                        .map(|(x, y)| {
                            if periodic { (x.rem_euclid(counts[0]), y.rem_euclid(counts[1])) } else { (x, y) }
                        })
                        .collect();
                around.sort_unstable();
                around.dedup();
                let mut sum = vec![[0.0_f64; 3]; n];
                let mut total = 0.0;
                for (x, y) in around {
                    let Some(list) = buckets.get(&(x, y, key.0, key.1)) else { continue };
                    for &j in list {
                        let mut d = position(j) - p;
                        if periodic {
                            d.x -= period.x * (d.x / period.x).round();
                            d.y -= period.y * (d.y / period.y).round();
                        }
                        let q = d.length_squared() / (radius_cm * radius_cm);
                        let other = &cells_read[first + j];
                        if q >= 1.0 || other.matrix.len() != n {
                            continue;
                        }
                        let w = other.paths as f64 * (1.0 - q);
                        total += w;
                        for (acc, v) in sum.iter_mut().zip(&other.matrix) {
                            for c in 0..3 {
                                acc[c] += w * f64::from(v[c]);
                            }
                        }
                    }
                }
                #[allow(clippy::cast_possible_truncation)]
                let matrix = sum.iter().map(|a| a.map(|v| (v / total) as f32)).collect();
                (k, matrix)
            })
            .collect();
    for (k, matrix) in pooled {
        cells[first + k].matrix = matrix;
    }
}

/// The IIRTF of cells `cells` of `grid` only, in order: each cell draws from its own stream,
/// so a range baked alone equals the same cells of a whole bake (what a shard of a sharded
/// bake computes, `shard.rs`). What a segment cell holds depends on the lattice's lobes
/// ([`segment_cell_light`]): with fiber lobes, a range that reaches the segment cells bakes the
/// whole lattice first (a shard's share of it again), as the whole bake does.
#[allow(clippy::too_many_arguments)]
pub fn bake_iirtf_cells(
    exemplar: &Exemplar,
    yarn_materials: &[Material],
    grid: &CellGrid,
    settings: &BakeSettings,
    options: &IirtfOptions,
    cells: std::ops::Range<usize>,
    cancel: &Cancel,
    progress: Progress<'_>,
) -> Result<Vec<CellTransfer>, IirtfError> {
    let lattice = grid.lattice_cell_count();
    let cells = cells.start.min(grid.cell_count())..cells.end.min(grid.cell_count());
    let lobes = settings.fiber_lobes && options.part == TransferPart::All;
    let all = |_: u32| Some(MatrixLight::All);
    if cells.end <= lattice || !lobes {
        // No lattice cell keeps lobes (or none of these cells is a segment cell): every segment
        // cell holds all of its light.
        return bake_cells_where(
            exemplar,
            yarn_materials,
            grid,
            settings,
            *options,
            cells,
            cancel,
            progress,
            &all,
        );
    }
    // The lattice first, then the segment cells, progress weighted by paths.
    let paths = settings.cell_paths();
    let lattice_work =
        (0..lattice as u32).filter(|&c| !grid.segments_in_cell(c).is_empty()).count() * paths.lattice;
    let segment_work = grid.segment_count() * paths.segment;
    let share = lattice_work as f64 / (lattice_work + segment_work).max(1) as f64;
    let lattice_cells = bake_cells_where(
        exemplar,
        yarn_materials,
        grid,
        settings,
        *options,
        0..lattice,
        cancel,
        &|f| progress(f * share),
        &all,
    )?;
    let reflected_fits = reflected_light_fits_matrices(&lattice_cells, settings.sh_order);
    // What each segment cell holds, so that the lattice's cells move into the output instead
    // of being copied (a copy would double the lattice's share of a bake's peak memory).
    let segment_light: Vec<Option<MatrixLight>> = (lattice..grid.cell_count())
        .map(|c| segment_cell_light(grid, &lattice_cells, reflected_fits, c as u32))
        .collect();
    let holds =
        |c: u32| (c as usize).checked_sub(lattice).and_then(|k| segment_light.get(k)).copied().flatten();
    let mut out = lattice_cells;
    out.drain(..cells.start.min(lattice));
    out.extend(bake_cells_where(
        exemplar,
        yarn_materials,
        grid,
        settings,
        *options,
        cells.start.max(lattice)..cells.end,
        cancel,
        &|f| progress(share + f * (1.0 - share)),
        &holds,
    )?);
    Ok(out)
}

/// What a segment cell's matrix holds (`bake::cells`), or `None` where it is not baked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatrixLight {
    /// All of the light (a lattice cell without lobes, and a segment cell whose lattice cell
    /// keeps none).
    All,
    /// The light reflected at least once: a segment cell whose lattice cell keeps fiber lobes,
    /// shaded beside the lattice cells' forward lobes.
    Reflected,
}

/// What segment cell `cell` of `grid` holds, given the lattice's cells (`lattice`): all of its
/// light where its segment's lattice cell keeps no lobes; where that cell keeps lobes that
/// carry light, its reflected light if the fabric's reflected light fits matrices of the
/// bake's order (`reflected_fits`, [`reflected_light_fits_matrices`]), else nothing (the
/// segment is shaded with its lattice cells' lobes alone).
#[must_use]
pub fn segment_cell_light(
    grid: &CellGrid,
    lattice: &[CellTransfer],
    reflected_fits: bool,
    cell: u32,
) -> Option<MatrixLight> {
    let segment = cell.checked_sub(lattice.len() as u32)?;
    let own = lattice.get(grid.cell_of_segment(segment) as usize)?;
    if own.keeps_lobe_light() {
        reflected_fits.then_some(MatrixLight::Reflected)
    } else {
        Some(MatrixLight::All)
    }
}

/// The most power of the reflected light's longitudinal offset Δθ (its arrival's angle to the
/// fiber against the light's, [`FiberOffset`]) in the harmonics above the transfer's SH order,
/// `Σ_{k>L} (c̄_k² + s̄_k²)` with `c̄_k = E cos kΔθ`, `s̄_k = E sin kΔθ` over the reflected
/// light of the lattice cells that keep lobes, that still lets a segment cell hold its
/// reflected light in a matrix ([`reflected_light_fits_matrices`]).
///
/// A matrix of order L holds the arrival directions' harmonics up to L. The reflected light of
/// parallel fibers keeps the light's angle to them (`docs/MATH.md`, "Fiber lobes"): its Δθ has a
/// core as narrow as the chains that carry it, which a matrix blurs across the fiber's scattering
/// cone, where it reaches eyes that the exact light misses. On the silk satin (power 0.60 in
/// harmonics 5–24 at order 4, interactive bake) reflected-light matrices made the dim raking
/// configurations of `twill accuracy` up to 2.9 times too bright (multiple scattering,
/// configuration 68: +191% against −9% with the lobes), and a silk with the gabardine's 7.2°
/// reflection lobe (0.21) still 2.3 times; the gabardine (0.11) came out nearer the path tracer
/// on almost every configuration, the cotton (0.12) too (`docs/BENCHMARKS.md`, "The reflected
/// light of a segment"). The bound lies between the two groups.
pub const REFLECTED_TAIL_MAX: f64 = 0.15;

/// Whether segment cells under lobes hold their reflected light in matrices: the power of the
/// lobe cells' reflected light in longitudinal harmonics above `order` is at most
/// [`REFLECTED_TAIL_MAX`] ([`reflected_light_tail`]). False without lobe cells.
#[must_use]
pub fn reflected_light_fits_matrices(lattice: &[CellTransfer], order: usize) -> bool {
    reflected_light_tail(lattice, order).is_some_and(|tail| tail <= REFLECTED_TAIL_MAX)
}

/// `Σ_{k=order+1..=K} (c̄_k² + s̄_k²)`, K = [`LOBE_FOURIER_TERMS`], of the reflected light's
/// longitudinal offset pooled over the cells that keep lobes and over the light's angle to the
/// fiber (every [`LOBE_LONGITUDINAL_BINS`] node and colour channel; each cell's sums weighted
/// by its reflected light, as its shape holds them); `None` where no cell keeps lobes with reflected
/// light. Pooled over the fabric, not per cell: one cell's 480 paths leave each of its
/// coefficients about ±0.3 of noise.
#[must_use]
pub fn reflected_light_tail(lattice: &[CellTransfer], order: usize) -> Option<f64> {
    let mut sums = [0.0f64; 2 * LOBE_FOURIER_TERMS];
    let mut total = 0.0f64;
    for cell in lattice.iter().filter(|c| c.keeps_lobe_light() && c.reflected_shape.len() == LOBE_SHAPE_LEN) {
        for shape in cell.reflected_shape.chunks_exact(LOBE_CHANNEL_SHAPE_LEN) {
            total += shape[LOBE_LONGITUDINAL_TOTALS..LOBE_LONGITUDINAL_AT]
                .iter()
                .map(|&v| f64::from(v))
                .sum::<f64>();
            for node in shape[LOBE_LONGITUDINAL_AT..].chunks_exact(2 * LOBE_FOURIER_TERMS) {
                for (sum, &v) in sums.iter_mut().zip(node) {
                    *sum += f64::from(v);
                }
            }
        }
    }
    (total > 0.0).then(|| sums.iter().skip(2 * order).map(|v| (v / total).powi(2)).sum())
}

/// [`bake_iirtf_cells`]: a segment cell's matrix holds the light `segment_cell_holds(cell)`
/// says, or the cell is left empty where it says `None`.
#[allow(clippy::too_many_arguments)]
fn bake_cells_where(
    exemplar: &Exemplar,
    yarn_materials: &[Material],
    grid: &CellGrid,
    settings: &BakeSettings,
    options: IirtfOptions,
    cells: std::ops::Range<usize>,
    cancel: &Cancel,
    progress: Progress<'_>,
    segment_cell_holds: &(dyn Fn(u32) -> Option<MatrixLight> + Sync),
) -> Result<Vec<CellTransfer>, IirtfError> {
    if grid.segment_count() != exemplar.segment_count() {
        return Err(IirtfError::GridMismatch {
            grid: grid.segment_count(),
            exemplar: exemplar.segment_count(),
        });
    }
    // One scene shared by every worker (a copy each would grow with the machine's cores).
    let sampler = TransferSampler::new(exemplar, yarn_materials, options.light_domain)?
        .with_part(options.part)
        .with_colour_aware_walk(options.colour_aware_walk)
        .with_exposed_starts(settings.exposed_starts)
        .with_light_samples(settings.iirtf_light_samples);
    let order = settings.sh_order;
    let paths = settings.cell_paths();
    let lobes = settings.fiber_lobes && options.part == TransferPart::All;
    Ok(for_each_cell(
        grid,
        cells,
        paths,
        settings.seed,
        cancel,
        progress,
        &|cell, segments, stream, tick| {
            if !grid.is_segment_cell(cell) {
                return bake_cell(
                    &sampler,
                    segments,
                    order,
                    paths.lattice,
                    lobes,
                    MatrixLight::All,
                    stream,
                    tick,
                );
            }
            let Some(holds) = segment_cell_holds(cell).filter(|_| sampler.eye_sees(segments[0], stream))
            else {
                return tick(paths.segment).then(CellTransfer::empty);
            };
            // Matrices only: the lobes of a segment under lobes are its lattice cells'.
            bake_cell(&sampler, segments, order, paths.segment, false, holds, stream, tick)
        },
    )?)
}

/// What [`for_each_cell`] runs per cell: `(cell, segments, stream, tick)` to the cell's
/// result, or `None` when `tick(paths done)` returned false (cancelled).
pub(crate) type CellJob<'a, T> = &'a (dyn Fn(u32, &[u32], u64, &dyn Fn(usize) -> bool) -> Option<T> + Sync);

/// Runs `job` on every cell of `cells` of `grid` (clamped to the grid) in parallel, one worker
/// per rayon thread pulling whole cells from a shared counter, and returns the results in cell
/// order. Cell c draws from [`cell_stream`]`(seed, c)`; `paths` of each nonempty cell is what
/// progress counts.
pub(crate) fn for_each_cell<T: Send>(
    grid: &CellGrid,
    cells: std::ops::Range<usize>,
    paths: CellPaths,
    seed: u64,
    cancel: &Cancel,
    progress: Progress<'_>,
    job: CellJob<'_, T>,
) -> Result<Vec<T>, Cancelled> {
    let cells = cells.start.min(grid.cell_count())..cells.end.min(grid.cell_count());
    let nonempty = cells.clone().filter(|&c| !grid.segments_in_cell(c as u32).is_empty());
    let total_paths = nonempty.clone().map(|c| paths.of(grid, c as u32)).sum::<usize>().max(1) as f64;
    let workers = rayon::current_num_threads().clamp(1, nonempty.count().max(1));
    cancel.check()?;
    let next_cell = AtomicUsize::new(cells.start);
    let paths_done = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let results: Mutex<Vec<Option<T>>> = Mutex::new((0..cells.len()).map(|_| None).collect());
    let end = cells.end;
    rayon::scope(|scope| {
        for _ in 0..workers {
            let (next_cell, paths_done, stop, results) = (&next_cell, &paths_done, &stop, &results);
            let first = cells.start;
            scope.spawn(move |_| {
                loop {
                    let c = next_cell.fetch_add(1, Ordering::Relaxed);
                    if c >= end || stop.load(Ordering::Relaxed) {
                        return;
                    }
                    let cell = job(
                        c as u32,
                        grid.segments_in_cell(c as u32),
                        cell_stream(seed, c as u32),
                        &|done| {
                            if cancel.is_cancelled() {
                                stop.store(true, Ordering::Relaxed);
                                return false;
                            }
                            let all = paths_done.fetch_add(done, Ordering::Relaxed) + done;
                            progress(all as f64 / total_paths);
                            true
                        },
                    );
                    let Some(cell) = cell else { return };
                    results.lock().expect("a worker panicked")[c - first] = Some(cell);
                }
            });
        }
    });
    cancel.check()?;
    let cells = results
        .into_inner()
        .expect("a worker panicked")
        .into_iter()
        .map(|c| c.expect("every cell baked"))
        .collect();
    progress(1.0);
    Ok(cells)
}

/// The sharpness below which a cell keeps its transfer in its SH matrix instead of fiber
/// lobes, at SH order `order`: `(L+1)(L+2)/FORWARD_LOBE_BAND_DIVISOR`, read from the forward
/// chains' mean cosine to the light ([`forward_sharpness`]). A normalized SG's band-l zonal
/// coefficient falls as about `exp(−l(l+1)/(2λ))`, so below this λ the bands above L hold
/// little of it and the SH transfer carries the cell's light as well as lobes do (the default
/// cotton's forward light, λ 0.6–3.3, came out 30% dark as an isotropic lobe, before the lobes
/// had shapes), and above it the SH rings (the silk satin's, λ 5–11, up to 12 times too bright
/// at order 4; the gabardine's, which folded below λ 5 until 2026-11-27: multiple scattering
/// of a grazing front-lit view −31% with a mean of −54% under the clamp at zero, of a backlit
/// one +24%; docs/BENCHMARKS.md, "The gabardine's forward chains").
///
/// From order 2 on, never below [`FORWARD_LOBE_FLOOR`]: at the draft's order 2 the formula
/// alone (λ 1.2) gave lobes to the default cotton's broad forward light, which the lobes'
/// model takes too dark (multiple scattering of the view-lit SG cases of
/// `tests/shading_vs_reference.rs` −9.5% → −15.8% at λ 8, −12.1% → −15.9% at λ 300,
/// 2026-11-28). Orders 0 and 1 keep the formula: no preset uses them, and the unit tests that
/// do (on tiny fabrics, for speed) check the lobes' bookkeeping, not their accuracy.
#[must_use]
pub fn forward_lobe_min_sharpness(order: usize) -> f64 {
    let l = order as f64;
    let formula = (l + 1.0) * (l + 2.0) / FORWARD_LOBE_BAND_DIVISOR;
    if order >= 2 { formula.max(FORWARD_LOBE_FLOOR) } else { formula }
}

/// The least forward sharpness for which a cell keeps fiber lobes at SH order 2 and above:
/// the interactive preset's (order 4).
pub const FORWARD_LOBE_FLOOR: f64 = 3.0;

/// See [`forward_lobe_min_sharpness`]: 10 puts the first band left out at about `e^{−5}` of
/// the lobe's constant term (λ 3 at order 4). At 6 (`e^{−3}`, λ 5) the gabardine's forward
/// chains stayed in matrices that rang at order 4.
pub const FORWARD_LOBE_BAND_DIVISOR: f64 = 10.0;

/// Whether a cell at SH order `order` keeps its light in its matrix rather than in fiber
/// lobes, from its forward (0) coefficient and forward cosine: their sharpness
/// ([`forward_sharpness`]) below [`forward_lobe_min_sharpness`]. The sharpness is a ratio of
/// the two, so they may be sums or means alike. The bake's rule, which the recolouring basis
/// applies at its colours (`recolour::forward_lobe_folds`).
#[must_use]
pub fn folds_lobes(order: usize, forward0: Rgb, forward_cosine: Rgb) -> bool {
    crate::shading::multiple::forward_sharpness(forward0, forward_cosine) < forward_lobe_min_sharpness(order)
}

/// One cell's transfer from `paths` paths. With `lobes` (`BakeSettings::fiber_lobes`), every
/// light connection also goes to the two lobes' sums, split into its forward-chain share and
/// the rest: their strength over ω0 (SH at [`LOBE_SH_ORDER`]) and their shape
/// ([`FiberOffset`] in the start segment's frame), and the forward chains' cosine to the
/// arrival direction ω1. A cell whose forward light turns out sharp
/// ([`forward_lobe_min_sharpness`]) then keeps the lobes and a zero matrix; any other keeps
/// its matrix and no lobes. `holds` says which light the matrix sums (a segment cell under
/// lobes: [`MatrixLight::Reflected`]; with lobes the two parts are split anyway).
/// `tick(paths)` is called every [`CHECK_EVERY`] paths and returns false to stop (then `None`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn bake_cell(
    sampler: &TransferSampler,
    segments: &[u32],
    order: usize,
    paths: usize,
    lobes: bool,
    holds: MatrixLight,
    stream: u64,
    tick: &dyn Fn(usize) -> bool,
) -> Option<CellTransfer> {
    let n = sh_count(order);
    if segments.is_empty() || paths == 0 {
        return Some(CellTransfer::empty());
    }
    let mut sum = vec![Rgb::ZERO; n * n];
    let mut sum2 = vec![Rgb::ZERO; n * n];
    let (mut y0, mut y1) = (ConnectionSh::new(order, lobes), vec![0.0; n]);
    let mut light = vec![Rgb::ZERO; n];
    let lobe_n = if lobes { sh_count(LOBE_SH_ORDER) } else { 0 };
    let mut forward = vec![Rgb::ZERO; lobe_n];
    let mut reflected = vec![Rgb::ZERO; lobe_n];
    let mut forward_cosine = Rgb::ZERO;
    let mut shapes = [vec![0.0; LOBE_SHAPE_LEN], vec![0.0; LOBE_SHAPE_LEN]];
    for p in 0..paths {
        if p % CHECK_EVERY == CHECK_EVERY - 1 && !tick(CHECK_EVERY) {
            return None;
        }
        let s = sampler.sample(segments, stream, p as u64);
        if s.lights.is_empty() {
            continue;
        }
        // The path's light-side SH vector: Σ over its events of weight · Y(ω0).
        light.fill(Rgb::ZERO);
        let tangent = sampler.tangent(s.segment);
        for ((to_light, weight), share) in s.lights.iter().zip(&s.forward) {
            y0.eval(*to_light);
            let held = match holds {
                MatrixLight::All => *weight,
                MatrixLight::Reflected => *weight - *share,
            };
            for (l, y) in light.iter_mut().zip(y0.matrix()) {
                *l += held * *y;
            }
            if lobes {
                let rest = *weight - *share;
                for ((f, r), y) in forward.iter_mut().zip(reflected.iter_mut()).zip(y0.lobe()) {
                    *f += *share * *y;
                    *r += rest * *y;
                }
                forward_cosine += *share * to_light.dot(s.view);
                FiberOffset::new(tangent, *to_light, s.view).accumulate_rgb([*share, rest], &mut shapes);
            }
        }
        sh_eval(order, s.view, &mut y1);
        for (j1, (row, row2)) in sum.chunks_exact_mut(n).zip(sum2.chunks_exact_mut(n)).enumerate() {
            for ((a, a2), l) in row.iter_mut().zip(row2.iter_mut()).zip(&light) {
                let v = *l * y1[j1];
                *a += v;
                *a2 += v * v;
            }
        }
    }
    tick(paths % CHECK_EVERY);
    let count = paths as f64;
    let keeps_lobes = lobes && !folds_lobes(order, forward[0] / count, forward_cosine / count);
    let to_f32 = |v: Rgb| v.as_vec3().to_array();
    if keeps_lobes {
        let lobe = |v: &[Rgb]| v.iter().map(|f| to_f32(*f / count)).collect();
        let shape = |v: &[f64]| v.iter().map(|t| (t / count) as f32).collect();
        return Some(CellTransfer {
            paths,
            matrix: vec![[0.0; 3]; n * n],
            std_error: vec![[0.0; 3]; n * n],
            forward: lobe(&forward),
            forward_cosine: to_f32(forward_cosine / count),
            reflected: lobe(&reflected),
            forward_shape: shape(&shapes[0]),
            reflected_shape: shape(&shapes[1]),
        });
    }
    let matrix = sum.iter().map(|s| to_f32(*s / count)).collect();
    let std_error = sum
        .iter()
        .zip(&sum2)
        .map(|(s, s2)| {
            let m = *s / count;
            to_f32(if paths > 1 {
                ((*s2 / count - m * m).max(Rgb::ZERO) / (count - 1.0)).powf(0.5)
            } else {
                Rgb::ZERO
            })
        })
        .collect();
    Some(CellTransfer { paths, matrix, std_error, ..CellTransfer::empty() })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::cs_table::{OmegaOSpace, cs_coefficients};
    use crate::bake::no_progress;
    use crate::bake::settings::Quality;
    use crate::fabric::presets::fabric_preset;
    use crate::pathtrace::integrator::{Component, PathScene, RenderSettings, radiance_from};
    use crate::pathtrace::light::Light;
    use crate::raycast::mean_free_path;
    use crate::sh::ShRotation;
    use std::path::Path;

    /// The default preset's exemplar and per-yarn materials.
    fn default_fabric() -> (Exemplar, Vec<Material>) {
        let preset = fabric_preset("default").unwrap();
        let exemplar = preset.fabric.build(Path::new(".")).unwrap();
        let materials = [
            Material::from_desc(&preset.warp_material).unwrap(),
            Material::from_desc(&preset.weft_material).unwrap(),
        ];
        let yarn = exemplar.yarns.iter().map(|y| materials[(y.material as usize).min(1)].clone()).collect();
        (exemplar, yarn)
    }

    /// Cells `range` of `grid` baked with the default options.
    fn bake_range(
        exemplar: &Exemplar,
        materials: &[Material],
        grid: &CellGrid,
        settings: &BakeSettings,
        range: std::ops::Range<usize>,
    ) -> Vec<CellTransfer> {
        bake_iirtf_cells(
            exemplar,
            materials,
            grid,
            settings,
            &IirtfOptions::default(),
            range,
            &Cancel::new(),
            &|_| {},
        )
        .unwrap()
    }

    #[test]
    fn exposed_starts_lie_on_the_fibers_outer_side_and_are_fewer_under_other_fibers() {
        let (exemplar, materials) = default_fabric();
        let sampler = TransferSampler::new(&exemplar, &materials, LightDomain::UpperHemisphere)
            .unwrap()
            .with_exposed_starts(true);
        let segments = exemplar.segments();
        let mut by_height: Vec<u32> = (0..segments.len() as u32).collect();
        by_height.sort_by(|&a, &b| {
            segments[a as usize].midpoint().z.total_cmp(&segments[b as usize].midpoint().z)
        });
        // The fabric's top and bottom 300 segments, as two "cells".
        let bottom = &by_height[..300];
        let top = &by_height[by_height.len() - 300..];
        let mut rng = pixel_rng(7, 0);
        let mut exposure = Vec::new();
        for cell in [top, bottom] {
            let (mut found, mut rise) = (0, 0.0);
            for first in 0..2_000 {
                let Some((k, start)) = sampler.exposed_start(cell, first % cell.len(), &mut rng) else {
                    continue;
                };
                assert!(cell.contains(&k), "start on segment {k}, not in the cell");
                // On the segment's surface, between its ends.
                let (mid, t) = (sampler.midpoint(k), sampler.tangent(k));
                let along = (start - mid).dot(t);
                let radial = (start - mid - along * t).length();
                assert!(
                    along.abs() <= sampler.half_lengths[k as usize] + 1e-9,
                    "start {along} along the axis"
                );
                let r = sampler.radii[k as usize];
                assert!(
                    (radial - r).abs() < 1e-6 * r.max(1e-3),
                    "start {radial} cm from the axis, radius {r}"
                );
                rise += (start.z - mid.z) / r;
                found += 1;
            }
            assert!(found > 0, "no exposed start in the cell");
            exposure.push(f64::from(found) / 2_000.0);
            if cell == top {
                // Eyes above see the upper sides of the top fibers.
                let mean_rise = rise / f64::from(found);
                assert!(mean_rise > 0.4, "top starts lie {mean_rise} radii above their axes");
            }
        }
        // Fibers under others are seen less often: a path there mostly starts at a midpoint.
        // (Measured: 1.0 and 0.04; the top starts 0.61 radii above their axes.)
        assert!(exposure[0] > 0.9 && exposure[1] < 0.25, "exposure top / bottom {exposure:?}");
    }

    #[test]
    fn segment_cells_are_baked_for_the_segments_an_eye_sees_and_hold_matrices_only() {
        let (exemplar, materials) = default_fabric();
        let settings = BakeSettings {
            iirtf_paths_per_cell: 8,
            segment_transfer_paths: 8,
            fiber_lobes: true,
            ..Quality::Draft.settings()
        };
        let grid = CellGrid::for_bake(&exemplar, 0.003, &settings).unwrap();
        let sampler = TransferSampler::new(&exemplar, &materials, LightDomain::UpperHemisphere)
            .unwrap()
            .with_exposed_starts(true);
        let seen = |k: u32| sampler.eye_sees(k, cell_stream(settings.seed, grid.segment_cell(k).unwrap()));
        let segments = exemplar.segments();
        let mut by_height: Vec<u32> = (0..segments.len() as u32).collect();
        by_height.sort_by(|&a, &b| {
            segments[a as usize].midpoint().z.total_cmp(&segments[b as usize].midpoint().z)
        });
        let share = |ks: &[u32]| ks.iter().filter(|&&k| seen(k)).count() as f64 / ks.len() as f64;
        let (bottom, top) = (share(&by_height[..300]), share(&by_height[by_height.len() - 300..]));
        // The top segments are seen; most of the bottom layer lies under the yarns above it
        // (measured: 0.99 and 0.097).
        assert!(top > 0.95 && bottom < 0.3, "seen: top {top}, bottom {bottom}");
        // The bake gives paths to exactly the segment cells an eye sees whose lattice cell keeps
        // no lobes, or keeps them and the fabric's reflected light fits matrices; and no lobes.
        let first = grid.lattice_cell_count();
        let bake = |range| bake_range(&exemplar, &materials, &grid, &settings, range);
        let lattice = bake(0..first);
        let fits = reflected_light_fits_matrices(&lattice, settings.sh_order);
        let cells = bake(first..first + 200);
        let mut held = [0usize; 3];
        for (k, cell) in cells.iter().enumerate() {
            let holds = segment_cell_light(&grid, &lattice, fits, (first + k) as u32);
            assert_eq!(cell.paths > 0, seen(k as u32) && holds.is_some(), "segment {k}");
            assert!(!cell.has_lobes() && cell.matrix.iter().flatten().all(|v| v.is_finite()));
            assert!(cell.paths == 0 || cell.paths == settings.segment_transfer_paths);
            held[match holds {
                None => 0,
                Some(MatrixLight::All) => 1,
                Some(MatrixLight::Reflected) => 2,
            }] += 1;
        }
        eprintln!(
            "segment cells: none {}, all light {}, reflected light {} (fits: {fits})",
            held[0], held[1], held[2]
        );
        assert!(held[1] > 0, "no segment cell holds all of its light: {held:?}");
    }

    /// Segment cells pooled with their neighbours ([`pool_segment_cells`], 0.5ℓ) lie closer
    /// to their own transfer than the raw few-path estimate: the default
    /// fabric (SH order 3, no lobes, so every seen segment holds all of its light), 16 paths a
    /// segment cell, against 1,024 paths of 100 of the seen segments.
    #[test]
    fn pooled_segment_cells_are_nearer_their_own_transfer() {
        let (exemplar, materials) = default_fabric();
        let mfp = 0.003;
        let settings = BakeSettings {
            sh_order: 3,
            iirtf_paths_per_cell: 96,
            segment_transfer_paths: 16,
            fiber_lobes: false,
            ..Quality::Draft.settings()
        };
        let grid = CellGrid::for_bake(&exemplar, mfp, &settings).unwrap();
        let first = grid.lattice_cell_count();
        let bake = |paths: usize, range| {
            bake_range(
                &exemplar,
                &materials,
                &grid,
                &BakeSettings { segment_transfer_paths: paths, ..settings },
                range,
            )
        };
        let mut cells = bake(16, 0..grid.cell_count());
        let raw = cells.clone();
        pool_segment_cells(&exemplar, &grid, &mut cells, 0.5 * mfp);
        // 100 seen segments spread over the exemplar, their own transfer from 1,024 paths.
        let seen: Vec<usize> = (0..grid.segment_count()).filter(|&k| raw[first + k].paths > 0).collect();
        let chosen: Vec<usize> = seen.iter().step_by(seen.len() / 100).take(100).copied().collect();
        let squared = |a: &CellTransfer, b: &CellTransfer| -> f64 {
            a.matrix
                .iter()
                .zip(&b.matrix)
                .flat_map(|(x, y)| (0..3).map(move |c| f64::from(x[c] - y[c]).powi(2)))
                .sum()
        };
        let (mut e_raw, mut e_pooled, mut e_lattice) = (0.0, 0.0, 0.0);
        for &k in &chosen {
            let truth = &bake(1024, first + k..first + k + 1)[0];
            e_raw += squared(&raw[first + k], truth);
            e_pooled += squared(&cells[first + k], truth);
            e_lattice += squared(&cells[grid.cell_of_segment(k as u32) as usize], truth);
            assert!(cells[first + k].matrix.iter().flatten().all(|v| v.is_finite()), "segment {k}");
        }
        // The lattice and the segment cells nobody sees are left as they were.
        assert!(cells.iter().zip(&raw).enumerate().all(|(c, (a, b))| (c >= first && b.paths > 0) || a == b));
        eprintln!(
            "{} seen of {} segments; squared error raw {e_raw:.4e}, pooled {e_pooled:.4e}, lattice {e_lattice:.4e}",
            seen.len(),
            grid.segment_count()
        );
        // Measured: raw 239, pooled 71, lattice 50. The lattice cell's error is its bias (its
        // fibers' other sides) and little noise; what the segment cells gain over it shows in
        // the image means of `twill accuracy` (docs/BENCHMARKS.md), not in this sum over
        // entries, which the high bands' noise dominates.
        assert!(e_pooled < 0.4 * e_raw, "raw {e_raw}, pooled {e_pooled}, lattice {e_lattice}");
    }

    /// Pooling weighs the seen segments of the same yarn within the radius by paths and
    /// `1 − d²/r²` (across the period), and nothing else: a segment of another yarn beside
    /// them and an unseen one keep what they had, and a radius of 0 changes nothing.
    #[test]
    fn pooling_takes_the_seen_segments_of_the_same_yarn_within_the_radius() {
        let (exemplar, _) = default_fabric();
        let settings = BakeSettings { segment_transfer_paths: 8, ..Quality::Draft.settings() };
        let grid = CellGrid::for_bake(&exemplar, 0.003, &settings).unwrap();
        let first = grid.lattice_cell_count();
        let segments = exemplar.segments();
        let radius = 0.002;
        let at = |k: usize| segments[k].midpoint().as_dvec3();
        // Segment 0 and the nearest segment of its yarn on another fiber; one of another yarn.
        let near = |yarn_same: bool| {
            (1..segments.len())
                .filter(|&j| (segments[j].yarn == segments[0].yarn) == yarn_same && segments[j].fiber != 0)
                .min_by(|&a, &b| at(a).distance(at(0)).total_cmp(&at(b).distance(at(0))))
                .unwrap()
        };
        let (same, other) = (near(true), near(false));
        let d = at(same).distance(at(0));
        assert!(d < radius, "nearest segment of the same yarn {d} cm away");
        let n = sh_count(2) * sh_count(2);
        let cell = |paths: usize, v: f32| CellTransfer {
            paths,
            matrix: vec![[v; 3]; n],
            std_error: vec![[0.0; 3]; n],
            ..CellTransfer::empty()
        };
        let mut cells: Vec<CellTransfer> = (0..first).map(|_| cell(96, 0.2)).collect();
        cells.extend((0..grid.segment_count()).map(|k| match k {
            0 => cell(8, 1.0),
            k if k == same => cell(24, 2.0),
            k if k == other => cell(8, 5.0),
            _ => CellTransfer::empty(),
        }));
        let before = cells.clone();
        pool_segment_cells(&exemplar, &grid, &mut cells, 0.0);
        assert_eq!(cells, before, "radius 0");
        pool_segment_cells(&exemplar, &grid, &mut cells, radius);
        // Each takes itself at weight paths · 1 and the other at paths · (1 − d²/r²).
        let falloff = 1.0 - (d / radius).powi(2);
        let pooled = |(own_paths, own): (f64, f64), (paths, value): (f64, f64)| {
            ((own_paths * own + falloff * paths * value) / (own_paths + falloff * paths)) as f32
        };
        for (k, expected) in [(0, pooled((8.0, 1.0), (24.0, 2.0))), (same, pooled((24.0, 2.0), (8.0, 1.0)))] {
            let got = cells[first + k].matrix[0][0];
            assert!(
                cells[first + k].matrix.iter().flatten().all(|&v| (v - expected).abs() < 1e-5),
                "segment {k}: {got}, expected {expected}"
            );
        }
        assert_eq!(cells[first + other], before[first + other], "another yarn's segment");
        assert!(cells[..first] == before[..first] && cells[first + 1].is_empty());
    }

    /// A segment cell under fiber lobes sums, on the same paths, exactly what the transfer's
    /// part "light reflected at least once" sums ([`TransferPart::AfterReflection`]): the
    /// forward chains' share taken off every connection; its band-0 response lies below the
    /// whole light's.
    #[test]
    fn a_segment_cell_under_lobes_holds_the_light_reflected_at_least_once() {
        let (exemplar, materials) = default_fabric();
        let sampler = |part: TransferPart| {
            TransferSampler::new(&exemplar, &materials, LightDomain::UpperHemisphere)
                .unwrap()
                .with_part(part)
                .with_exposed_starts(true)
        };
        let (whole, after_reflection) = (sampler(TransferPart::All), sampler(TransferPart::AfterReflection));
        let k = exemplar.segment_count() as u32 / 2;
        let stream = cell_stream(1, k);
        let cell =
            |s: &TransferSampler, holds| bake_cell(s, &[k], 2, 96, false, holds, stream, &|_| true).unwrap();
        let reflected = cell(&whole, MatrixLight::Reflected);
        assert_eq!(reflected, cell(&after_reflection, MatrixLight::All));
        let all = cell(&whole, MatrixLight::All);
        let band0 = |c: &CellTransfer| c.matrix[0].iter().sum::<f32>();
        assert!(
            band0(&reflected) > 0.0 && band0(&reflected) < band0(&all),
            "{} {}",
            band0(&reflected),
            band0(&all)
        );
    }

    /// The fabric-wide test of [`reflected_light_fits_matrices`] on cells made to order: a
    /// reflected light whose longitudinal offset is a narrow core (every harmonic near 1) does
    /// not fit order 4, a broad one (a wrapped normal of 0.5 rad) does, and a lattice without
    /// lobe cells says no.
    #[test]
    fn reflected_light_fits_matrices_when_its_offset_lacks_harmonics_above_the_order() {
        let lobe_cell = |width: f64| {
            // The same offset in two longitudinal nodes, which the tail pools.
            let mut shape = vec![0.0f32; LOBE_SHAPE_LEN];
            shape[LOBE_AZIMUTH_TOTALS] = 2.0;
            for node in [1, LOBE_LONGITUDINAL_BINS - 2] {
                shape[LOBE_LONGITUDINAL_TOTALS + node] = 1.0;
                for k in 1..=LOBE_FOURIER_TERMS {
                    shape[LOBE_LONGITUDINAL_AT + node * 2 * LOBE_FOURIER_TERMS + 2 * (k - 1)] =
                        (-0.5 * (k as f64 * width).powi(2)).exp() as f32;
                }
            }
            let strength = vec![[0.1f32; 3]; sh_count(LOBE_SH_ORDER)];
            CellTransfer {
                paths: 1,
                matrix: vec![[0.0; 3]; 25],
                std_error: vec![[0.0; 3]; 25],
                forward: strength.clone(),
                forward_cosine: [0.0; 3],
                reflected: strength,
                forward_shape: shape.clone(),
                reflected_shape: shape,
            }
        };
        let narrow = vec![lobe_cell(0.01); 3];
        let broad = vec![lobe_cell(0.5); 3];
        assert!(reflected_light_tail(&narrow, 4).unwrap() > 15.0);
        assert!(reflected_light_tail(&broad, 4).unwrap() < 0.01);
        assert!(!reflected_light_fits_matrices(&narrow, 4));
        assert!(reflected_light_fits_matrices(&broad, 4));
        // A higher order leaves fewer of the narrow core's harmonics above it.
        assert!(reflected_light_tail(&narrow, 12).unwrap() < reflected_light_tail(&narrow, 4).unwrap());
        let without_lobes = vec![CellTransfer { paths: 1, ..CellTransfer::empty() }];
        assert_eq!(reflected_light_tail(&without_lobes, 4), None);
        assert!(!reflected_light_fits_matrices(&without_lobes, 4));
    }

    /// Small draft settings with the SH transfer alone (the tests of the lobes set them on).
    fn small_settings(paths: usize, order: usize) -> BakeSettings {
        BakeSettings {
            iirtf_paths_per_cell: paths,
            sh_order: order,
            fiber_lobes: false,
            ..Quality::Draft.settings()
        }
    }

    #[test]
    fn path_strata_follow_roberts_sequences_and_cover_each_group_evenly() {
        // α_i = g^−i with g^(d+1) = g + 1, for the groups R_1, R_2, R_3.
        for (first, d) in [(0, 1), (1, 2), (3, 3)] {
            let g = 1.0 / STRATA_STEPS[first];
            assert!((g.powi(d + 1) - g - 1.0).abs() < 1e-12, "R_{d}: g = {g}");
            for i in 0..d {
                let a = STRATA_STEPS[first + i as usize];
                assert!((a - g.powi(-(i + 1))).abs() < 1e-15, "R_{d}, α_{i} = {a}");
            }
        }
        // 160 paths of a cell: each dimension's 16 bins, and ω1's 4 x 4 bins, hold 10 ± 3
        // points. Independent draws (10 ± 3.2 per bin) keep all 16 bins of a dimension so close
        // in about 1% of cells; this holds in every cell.
        for cell in 0..50 {
            let stream = cell_stream(7, cell);
            let mut bins = [[0_u32; 16]; STRATA_DIMS + 1];
            for p in 0..160 {
                let u = path_strata(stream, p);
                for (d, v) in u.iter().enumerate() {
                    assert!((0.0..1.0).contains(v), "{v}");
                    bins[d][(v * 16.0) as usize] += 1;
                }
                bins[STRATA_DIMS][(u[1] * 4.0) as usize * 4 + (u[2] * 4.0) as usize] += 1;
            }
            for (d, b) in bins.iter().enumerate() {
                assert!(b.iter().all(|&n| (7..=13).contains(&n)), "cell {cell}, dimension {d}: {b:?}");
            }
        }
        // The shift differs between cells, so their points do too.
        let (a, b) = (path_strata(cell_stream(7, 0), 3), path_strata(cell_stream(7, 1), 3));
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() > 1e-9), "{a:?} {b:?}");
    }

    #[test]
    fn presets_walk_colour_free_and_white_yarns_follow_their_colours() {
        // Every preset's yarns lie below the colour-free walk's limit, so their bakes walk the
        // recolouring basis's paths; a unit-albedo fiber (the furnace) does not.
        for preset in crate::fabric::presets::fabric_presets() {
            let materials: Vec<Material> = [preset.warp_material, preset.weft_material]
                .iter()
                .map(|d| Material::from_desc(d).unwrap())
                .collect();
            assert!(walks_colour_free(&materials), "{}", preset.name);
        }
        let crate::bcsdf::MaterialDesc::Fiber(cotton) = fabric_preset("default").unwrap().warp_material
        else {
            panic!("the default warp is a fiber");
        };
        let white = |c_tt| {
            let desc = crate::bcsdf::MaterialDesc::Fiber(crate::bcsdf::FiberParams {
                c_r: Rgb::ZERO,
                c_tt,
                ..cotton
            });
            Material::from_desc(&desc).unwrap()
        };
        assert!(!walks_colour_free(&[white(Rgb::new(0.2, 1.0, 0.5))]));
        assert!(walks_colour_free(&[white(Rgb::splat(COLOUR_FREE_MAX_TAU))]));
    }

    #[test]
    fn the_colour_free_and_the_colour_aware_walks_agree_within_noise() {
        // The two walks a bake may take are two estimators of one transfer: the default
        // fabric's whole transfer (the constant term of every cell, per channel) by each, at
        // 16,000 paths per cell, within 4.5 standard errors of their difference. Measured:
        // colour-free +2.0% / +1.5% / +0.8% of the colour-aware (+1.0 / +0.8 / +0.5 sigma).
        let (exemplar, materials) = default_fabric();
        assert!(walks_colour_free(&materials));
        let grid = CellGrid::new(&exemplar, 0.01, 8.0, 8.0).unwrap();
        let settings = small_settings(16_000, 1);
        let total = |colour_aware_walk| {
            let options = IirtfOptions { colour_aware_walk, ..IirtfOptions::default() };
            let iirtf =
                bake_iirtf(&exemplar, &materials, &grid, &settings, &options, &Cancel::new(), &no_progress)
                    .unwrap();
            let (mut sum, mut var) = (Rgb::ZERO, Rgb::ZERO);
            for c in iirtf.cells.iter().filter(|c| !c.is_empty()) {
                sum += glam::Vec3::from(c.matrix[0]).as_dvec3();
                var += glam::Vec3::from(c.std_error[0]).as_dvec3().powf(2.0);
            }
            (sum, var)
        };
        let ((free, var_free), (aware, var_aware)) = (total(false), total(true));
        for ch in 0..3 {
            let sigma = (var_free[ch] + var_aware[ch]).sqrt();
            let z = (free[ch] - aware[ch]) / sigma;
            eprintln!(
                "channel {ch}: colour-free {:.5}, colour-aware {:.5} ({:+.2}%, {z:+.2} sigma)",
                free[ch],
                aware[ch],
                100.0 * (free[ch] / aware[ch] - 1.0)
            );
            assert!(z.abs() < 4.5, "channel {ch}: {} against {} ({z:.2} sigma)", free[ch], aware[ch]);
        }
    }

    /// The IIRTF of every cell of `grid`, with the default options and nothing cancelling it.
    fn bake_whole(
        exemplar: &Exemplar,
        materials: &[Material],
        grid: &CellGrid,
        settings: &BakeSettings,
    ) -> Iirtf {
        bake_iirtf(
            exemplar,
            materials,
            grid,
            settings,
            &IirtfOptions::default(),
            &Cancel::new(),
            &no_progress,
        )
        .unwrap()
    }

    #[test]
    fn several_light_samples_an_event_estimate_the_same_transfer_with_less_noise() {
        // Each of an event's light samples carries its share, so the transfer's expectation is
        // the one-sample walk's: the default fabric's whole transfer (every cell's constant term,
        // per channel) at 1 and 4 samples, within 4.5 standard errors of their difference.
        // The noise of every coefficient (the paths' own standard errors, summed in quadrature
        // over cells and coefficients) falls: measured 0.65 of one sample's at 4,000 paths a cell.
        let (exemplar, materials) = default_fabric();
        let grid = CellGrid::new(&exemplar, 0.01, 8.0, 8.0).unwrap();
        let bake_with = |light_samples| {
            let settings = BakeSettings { iirtf_light_samples: light_samples, ..small_settings(4000, 2) };
            let iirtf = bake_whole(&exemplar, &materials, &grid, &settings);
            let (mut total, mut total_var, mut noise) = (Rgb::ZERO, Rgb::ZERO, 0.0);
            for c in iirtf.cells.iter().filter(|c| !c.is_empty()) {
                total += glam::Vec3::from(c.matrix[0]).as_dvec3();
                total_var += glam::Vec3::from(c.std_error[0]).as_dvec3().powf(2.0);
                noise +=
                    c.std_error.iter().map(|e| glam::Vec3::from(*e).as_dvec3().length_squared()).sum::<f64>();
            }
            (total, total_var, noise.sqrt())
        };
        let ((one, var_one, noise_one), (four, var_four, noise_four)) = (bake_with(1), bake_with(4));
        for ch in 0..3 {
            let z = (four[ch] - one[ch]) / (var_one[ch] + var_four[ch]).sqrt();
            eprintln!(
                "channel {ch}: 4 samples {:.5}, 1 sample {:.5} ({:+.2}%, {z:+.2} sigma)",
                four[ch],
                one[ch],
                100.0 * (four[ch] / one[ch] - 1.0)
            );
            assert!(z.abs() < 4.5, "channel {ch}: {} against {} ({z:.2} sigma)", four[ch], one[ch]);
        }
        let ratio = noise_four / noise_one;
        eprintln!("noise at 4 samples over 1: {ratio:.3}");
        assert!(ratio < 0.75, "4 light samples an event left {ratio:.3} of one sample's noise");
    }

    #[test]
    fn transfer_parts_split_the_same_paths_and_sum_to_the_whole() {
        let (exemplar, materials) = default_fabric();
        let grid = CellGrid::new(&exemplar, 0.01, 8.0, 8.0).unwrap();
        let settings = small_settings(1000, 2);
        let bake_part = |part| {
            let options = IirtfOptions { part, ..IirtfOptions::default() };
            bake_iirtf(&exemplar, &materials, &grid, &settings, &options, &Cancel::new(), &no_progress)
                .unwrap()
        };
        let all = bake_part(TransferPart::All);
        let total = |iirtf: &Iirtf| -> f64 {
            iirtf.cells.iter().flat_map(|c| &c.matrix).map(|e| f64::from(e[0]).abs()).sum()
        };
        // Two splits: by the first event's lobe and depth, and into forward chains and the rest.
        let by_first_event =
            [TransferPart::FirstTransmission, TransferPart::FirstReflection, TransferPart::Later]
                .map(bake_part);
        let by_chain = [TransferPart::ForwardChains, TransferPart::AfterReflection].map(bake_part);
        for parts in [&by_first_event[..], &by_chain[..]] {
            // Every part carries light (little is the first neighbour's reflection: the R cone
            // about a fiber seldom reaches the sky past its neighbours).
            for part in parts {
                assert!(total(part) > 0.0, "a part without light: {} of {}", total(part), total(&all));
            }
            for (c, a) in all.cells.iter().enumerate() {
                let scale = a.matrix.iter().flatten().fold(0.0_f32, |m, v| m.max(v.abs())).max(1e-30);
                for (i, x) in a.matrix.iter().enumerate() {
                    for ch in 0..3 {
                        let sum: f32 = parts.iter().map(|p| p.cells[c].matrix[i][ch]).sum();
                        assert!(
                            (x[ch] - sum).abs() <= 1e-5 * scale,
                            "cell {c}, entry {i}: {x:?} against {sum}"
                        );
                    }
                }
                assert!(parts.iter().all(|p| p.cells[c].paths == a.paths));
            }
        }
        // Light reflected at least once is never negative (the forward share of a weight is at
        // most the weight, channel by channel): its constant term is a mean of such weights.
        assert!(
            by_chain[1].cells.iter().filter_map(|c| c.matrix.first()).all(|e| e.iter().all(|&v| v >= 0.0))
        );
    }

    #[test]
    fn fiber_lobes_split_the_same_paths_and_broad_cells_keep_their_matrix() {
        let (exemplar, materials) = default_fabric();
        let grid = CellGrid::new(&exemplar, 0.01, 2.0, 2.0).unwrap();
        let order = 2;
        let n = sh_count(order);
        let settings = small_settings(600, order);
        let bake = |fiber_lobes| {
            let settings = BakeSettings { fiber_lobes, ..settings };
            bake_whole(&exemplar, &materials, &grid, &settings)
        };
        let (all, split) = (bake(false), bake(true));
        let cut = forward_lobe_min_sharpness(order);
        assert!((cut - FORWARD_LOBE_FLOOR).abs() < 1e-12, "order 2: (3 · 4) / 10 = 1.2, raised to the floor");
        let (mut lobes, mut folded) = (0, 0);
        let y0 = 1.0 / (4.0 * std::f64::consts::PI).sqrt();
        for (c, (a, b)) in all.cells.iter().zip(&split.cells).enumerate() {
            if a.is_empty() {
                assert!(b.is_empty() && !b.has_lobes());
                continue;
            }
            let scale = a.matrix.iter().flatten().fold(0.0_f32, |m, v| m.max(v.abs())).max(1e-30);
            let close = |x: f64, y: f64, what: &str| {
                assert!((x - y).abs() <= 2e-5 * f64::from(scale), "cell {c}, {what}: {x} against {y}");
            };
            if b.has_lobes() {
                lobes += 1;
                let f0 = glam::Vec3::from(b.forward[0]).as_dvec3();
                let cosine = glam::Vec3::from(b.forward_cosine).as_dvec3();
                let lambda = crate::shading::multiple::forward_sharpness(f0, cosine);
                assert!(lambda >= cut, "cell {c} kept lobes of λ {lambda} below {cut}");
                // All of the cell's light is in the lobes.
                assert!(b.matrix.iter().chain(&b.std_error).flatten().all(|v| *v == 0.0));
                // Row j1 = 0 of the whole matrix is (F + R)_j0 · Y_0(ω1): the two lobes' first
                // bands hold every connection, split by share (order 6's first n SH are order 2's).
                for ch in 0..3 {
                    for j0 in 0..n {
                        let lobes = f64::from(b.forward[j0][ch]) + f64::from(b.reflected[j0][ch]);
                        close(f64::from(a.matrix[j0][ch]), lobes * y0, "row 0");
                    }
                }
                // Shapes are sums of weight × cosines: no mean beyond ±1, in each channel's
                // shape against that channel's strength.
                for (strength, shape) in [(&b.forward, &b.forward_shape), (&b.reflected, &b.reflected_shape)]
                {
                    assert!(strength[0].iter().sum::<f32>() > 0.0, "cell {c}: both parts carry light");
                    for (ch, part) in shape.chunks_exact(LOBE_CHANNEL_SHAPE_LEN).enumerate() {
                        let total = f64::from(strength[0][ch]) / y0;
                        for v in part {
                            assert!(
                                f64::from(v.abs()) <= total * (1.0 + 1e-5) + 1e-12,
                                "cell {c}, channel {ch}: {v} beyond {total}"
                            );
                        }
                    }
                }
            } else {
                folded += 1;
                assert!(b.forward.is_empty() && b.reflected.is_empty() && b.forward_shape.is_empty());
                for (x, y) in a.matrix.iter().zip(&b.matrix) {
                    for ch in 0..3 {
                        close(f64::from(x[ch]), f64::from(y[ch]), "folded matrix");
                    }
                }
            }
        }
        // The default cotton's forward light is broad in most cells and sharp enough in some.
        eprintln!("{lobes} cells with lobes, {folded} with their matrix");
        assert!(lobes > 0 && folded > 0, "{lobes} cells with lobes, {folded} with their matrix");
    }

    #[test]
    fn bake_is_deterministic_across_thread_counts_and_cancellable() {
        let (exemplar, materials) = default_fabric();
        // Huge cells: few of them, so the test stays short.
        let grid = CellGrid::new(&exemplar, 0.01, 8.0, 8.0).unwrap();
        let settings = small_settings(300, 2);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| bake_whole(&exemplar, &materials, &grid, &settings))
        };
        let (one, two) = (run(1), run(2));
        assert_eq!(one, two);
        assert_eq!(one.cells.len(), grid.cell_count());
        for (c, cell) in one.cells.iter().enumerate() {
            assert!(cell.matrix.iter().chain(&cell.std_error).flatten().all(|v| v.is_finite()));
            assert_eq!(cell.is_empty(), cell.paths == 0);
            assert_eq!(cell.paths == 0, grid.segments_in_cell(c as u32).is_empty());
        }
        let noise = one.noise();
        assert!(noise.rms_entry > 0.0 && noise.rms_std_error > 0.0, "{noise:?}");
        let cancel = Cancel::new();
        cancel.cancel();
        let r = bake_iirtf(
            &exemplar,
            &materials,
            &grid,
            &settings,
            &IirtfOptions::default(),
            &cancel,
            &no_progress,
        );
        assert!(matches!(r, Err(IirtfError::Cancelled(_))));
    }

    #[test]
    fn stored_cells_are_held_as_read_and_checked_for_size() {
        let full = |paths| CellTransfer {
            paths,
            matrix: vec![[0.5, 0.25, -1.0]; 16],
            std_error: vec![[0.1; 3]; 16],
            forward: vec![[0.25; 3]; sh_count(LOBE_SH_ORDER)],
            forward_cosine: [0.2; 3],
            reflected: vec![[0.5; 3]; sh_count(LOBE_SH_ORDER)],
            forward_shape: vec![0.1; LOBE_SHAPE_LEN],
            reflected_shape: vec![-0.1; LOBE_SHAPE_LEN],
        };
        let iirtf = Iirtf {
            sh_order: 1,
            light_domain: LightDomain::UpperHemisphere,
            cells: vec![CellTransfer::empty(), full(7)],
        };
        let bytes = postcard::to_allocvec(&iirtf).unwrap();
        assert_eq!(postcard::from_bytes::<Iirtf>(&bytes).unwrap(), iirtf);
        assert_eq!(iirtf.cells[0].apply(&[1.0; 4]), vec![Rgb::ZERO; 4], "an empty cell transfers nothing");
        // (SH order 1: 4 x 4 entries.) A cell with paths but the wrong number of entries, and
        // an empty cell with entries.
        // Lobes of the wrong size, or only some of the four parts of them.
        let lobes_short = CellTransfer { reflected: vec![[0.5; 3]; 25], ..full(7) };
        let shape_missing = CellTransfer { reflected_shape: Vec::new(), ..full(7) };
        for cells in [
            vec![CellTransfer { matrix: vec![[0.0; 3]; 15], ..full(7) }],
            vec![full(0)],
            vec![lobes_short],
            vec![shape_missing],
        ] {
            let bad = Iirtf { cells, ..iirtf.clone() };
            let error = postcard::from_bytes::<Iirtf>(&postcard::to_allocvec(&bad).unwrap()).unwrap_err();
            assert!(matches!(error, postcard::Error::SerdeDeCustom), "{error:?}");
        }
    }

    /// Σ over paths of the SH prediction `c_S · (R_ωo A_C c_d)` averaged over the cell's
    /// segments, as per-path values (their mean is exactly the matrix prediction).
    struct ShPrediction {
        mean: Rgb,
        std_error: Rgb,
    }

    #[test]
    fn sh_multiple_scattering_matches_path_traced_reference() {
        let (exemplar, materials) = default_fabric();
        // C_S rows at each segment's exact θo (the table's interpolation is tested in cs_table).
        let cs_of = |m: &Material, order: usize, theta_o: f64| -> Vec<Rgb> {
            let Material::Fiber(f) = m else { panic!("fiber BCSDF expected") };
            cs_coefficients(f, order, theta_o)
        };
        let segments = exemplar.segments();
        let fiber_scene = FiberScene::new(&exemplar, Extent::Unbounded).unwrap();
        let mfp = mean_free_path(&fiber_scene, 4000, 3).mean_cm;
        drop(fiber_scene);
        let grid = CellGrid::new(&exemplar, mfp, 1.5, 1.5).unwrap();
        // The fullest cell.
        let cell = (0..grid.cell_count() as u32).max_by_key(|&c| grid.segments_in_cell(c).len()).unwrap();
        let in_cell = grid.segments_in_cell(cell);
        let light = DVec3::new(0.3, -0.4, 0.85).normalize();
        let wo = DVec3::new(-0.5, 0.2, 0.8).normalize();
        let sampler = TransferSampler::new(&exemplar, &materials, LightDomain::UpperHemisphere).unwrap();
        // The path tracer's scene: the same tiled fabric lit by a directional light of unit
        // irradiance, one sample of every scattering order.
        let scene = PathScene {
            fibers: FiberScene::new(&exemplar, Extent::Unbounded).unwrap(),
            yarn_materials: materials.clone(),
            lights: vec![Light::Directional { to_light: light, irradiance: Rgb::ONE }],
            ground_z: None,
            painted: None,
            pattern: None,
        };
        let render = RenderSettings { spp: 1, max_depth: MAX_DEPTH, component: Component::All, seed: 0 };

        // (a) Reference: E_k ∫ T(ω_d, ωi, μ_k) S(ωi, ωo) cos θi dωi, ωi from the BCSDF sampler.
        let reference_paths = 20_000;
        let (mut sum, mut sum2) = (Rgb::ZERO, Rgb::ZERO);
        for p in 0..reference_paths {
            let mut rng = pixel_rng(99, p);
            let k = in_cell[rng.random_range(0..in_cell.len())];
            let seg = &segments[k as usize];
            let t = seg.tangent().as_dvec3();
            let material = &materials[seg.yarn as usize];
            let n = crate::sg::frame_from_z(t).0;
            let u = [rng.random(), rng.random(), rng.random()];
            let mut x = Rgb::ZERO;
            if let Some((wi, pdf)) = material.sample(t, n, wo, u) {
                let weight = material.eval_cos(t, n, wi, wo) / pdf;
                let origin = sampler.midpoint(k);
                x = weight * radiance_from(&scene, origin, wi, Some(seg.fiber), &render, &mut rng);
            }
            sum += x;
            sum2 += x * x;
        }
        let count = reference_paths as f64;
        let reference = sum / count;
        let reference_err = ((sum2 / count - reference * reference) / (count - 1.0)).powf(0.5);

        // (b) SH, for several orders from the same paths.
        let iirtf_paths = 20_000;
        let stream = cell_stream(5, cell);
        let samples: Vec<TransferSample> =
            (0..iirtf_paths).map(|p| sampler.sample(in_cell, stream, p as u64)).collect();
        let predict = |order: usize| -> ShPrediction {
            let n = sh_count(order);
            // g = mean over segments of R_kᵀ C_S[θo,k]: the BCSDF expansion in world space.
            let mut g = vec![Rgb::ZERO; n];
            let (mut ch, mut world) = (vec![0.0; n], vec![0.0; n]);
            for &k in in_cell {
                let seg = &segments[k as usize];
                let space = OmegaOSpace::new(seg.tangent().as_dvec3(), wo);
                let c_s = cs_of(&materials[seg.yarn as usize], order, space.theta_o);
                let back = ShRotation::new(order, &space.world_to_local.transpose());
                for c in 0..3 {
                    for j in 0..n {
                        ch[j] = c_s[j][c];
                    }
                    back.apply(&ch, &mut world);
                    for j in 0..n {
                        g[j][c] += world[j] / in_cell.len() as f64;
                    }
                }
            }
            let mut c_d = vec![0.0; n];
            sh_eval(order, light, &mut c_d);
            let (mut y0, mut y1) = (vec![0.0; n], vec![0.0; n]);
            let (mut s, mut s2) = (Rgb::ZERO, Rgb::ZERO);
            for sample in &samples {
                sh_eval(order, sample.view, &mut y1);
                let view_part: Rgb = g.iter().zip(&y1).map(|(a, b)| *a * *b).sum();
                let mut x = Rgb::ZERO;
                for (to_light, weight) in &sample.lights {
                    sh_eval(order, *to_light, &mut y0);
                    let light_part: f64 = c_d.iter().zip(&y0).map(|(a, b)| a * b).sum();
                    x += *weight * view_part * light_part;
                }
                s += x;
                s2 += x * x;
            }
            let count = samples.len() as f64;
            let mean = s / count;
            ShPrediction { mean, std_error: ((s2 / count - mean * mean) / (count - 1.0)).powf(0.5) }
        };
        // The matrix route gives the same number as the per-path sums (to f32 rounding).
        let transfer =
            bake_cell(&sampler, in_cell, 4, iirtf_paths, false, MatrixLight::All, stream, &|_| true).unwrap();
        let p4 = predict(4);
        {
            let n = sh_count(4);
            let mut c_d = vec![0.0; n];
            sh_eval(4, light, &mut c_d);
            let c_t = transfer.apply(&c_d);
            let mut g_dot = Rgb::ZERO;
            for &k in in_cell {
                let seg = &segments[k as usize];
                let space = OmegaOSpace::new(seg.tangent().as_dvec3(), wo);
                let c_s = cs_of(&materials[seg.yarn as usize], 4, space.theta_o);
                let rot = ShRotation::new(4, &space.world_to_local);
                let (mut inp, mut out) = (vec![0.0; n], vec![0.0; n]);
                for c in 0..3 {
                    for j in 0..n {
                        inp[j] = c_t[j][c];
                    }
                    rot.apply(&inp, &mut out);
                    g_dot[c] +=
                        out.iter().zip(&c_s).map(|(a, b)| a * b[c]).sum::<f64>() / in_cell.len() as f64;
                }
            }
            // Equal up to the matrix's f32 entries (relative rounding 6e-8 each).
            assert!(
                (g_dot - p4.mean).abs().max_element() < 1e-6 * (1.0 + p4.mean.abs().max_element()),
                "{g_dot} vs {}",
                p4.mean
            );
        }
        let orders: Vec<(usize, ShPrediction)> = [2, 4, 6].into_iter().map(|l| (l, predict(l))).collect();
        for (l, p) in &orders {
            eprintln!(
                "order {l}: SH {} ± {}  reference {} ± {}  (cell {cell}, {} segments, mfp {mfp:.5} cm)",
                p.mean,
                p.std_error,
                reference,
                reference_err,
                in_cell.len()
            );
        }
        let p6 = &orders[2].1;
        // Truncation estimate: the change from order 4 to 6 (same paths, so mostly not noise).
        let truncation = (p4.mean - p6.mean).abs();
        let bound =
            4.0 * (p6.std_error * p6.std_error + reference_err * reference_err).powf(0.5) + truncation;
        assert!(reference.is_finite() && p6.mean.is_finite());
        assert!(
            (p6.mean - reference).abs().cmple(bound).all(),
            "SH {} vs reference {reference} (bound {bound})",
            p6.mean
        );
    }
}
