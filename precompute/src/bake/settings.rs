//! Bake settings: every knob of the precomputation, and the named quality presets.
//!
//! `paper` is the 2017 paper's configuration (128x128 visibility images, 48 PCA components,
//! Q = 48 SGs of sharpness 128, cells of about one mean free path, 50,000 paths per cell, SH
//! order 5, 512 θo values); `interactive` bakes the default fabric (~20k segments) in about 70
//! seconds on two cores (its 480 paths per cell keep the order-4 transfer's noise from showing
//! as flat patches, one per segment, in multiple scattering; its segment transfers, 480 paths
//! for each segment an eye sees, take two thirds of it and halve the cotton's error); `draft`
//! is the fastest useful bake, for the first picture (about 4 seconds).
//!
//! The IIRTF dominates the cost (about 20 µs per path, bound by ray casting), so the cheaper
//! presets use larger cells (the paper finds cells up to 2ℓ lose little; beyond that multiple
//! scattering darkens and gets blockier) and fewer paths per cell (noisier transfer matrices).
//! `docs/BENCHMARKS.md` has the measured times.

use crate::params::{ParamError, check_count, check_range};

/// The most visibility points per segment a bake takes ([`BakeSettings::visibility_points`]).
pub const MAX_VISIBILITY_POINTS: usize = 8;

/// Serde's default for knobs added after bakes were written: 1.
fn one() -> usize {
    1
}

/// Paths per IIRTF cell: in the lattice's cells and in the segment cells (`bake::cells`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CellPaths {
    pub lattice: usize,
    pub segment: usize,
}

impl CellPaths {
    /// The paths of cell `c` of `grid`.
    #[must_use]
    pub fn of(self, grid: &super::cells::CellGrid, c: u32) -> usize {
        if grid.is_segment_cell(c) { self.segment } else { self.lattice }
    }
}

/// The named quality presets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    Draft,
    Interactive,
    Paper,
}

/// Every knob of a bake.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BakeSettings {
    /// Visibility images are `svf_resolution` rows (θ) by `svf_resolution` columns (φ).
    pub svf_resolution: usize,
    /// Visibility is precomputed at this many points along each segment, the centres of equal
    /// pieces of it (`bake::svf`); a hit takes the image of the piece it lies on. 1: at the
    /// midpoint alone, as the paper. A long segment seen in part (the rest hidden under a
    /// crossing yarn) is lit as its visible part is, not as its midpoint is.
    #[serde(default = "one")]
    pub visibility_points: usize,
    /// PCA components kept for the SSDFs.
    pub pca_components: usize,
    /// Keep the binary visibility images (one bit a pixel) beside the PCA SSDF, and read local
    /// visibility from them: directional and sharp SG lights (the erf path) take the images'
    /// visible fraction toward the light, bilinear between pixel centres. PCA's least squares
    /// move a segment's edges toward its neighbours': at raking light, where most lit points
    /// sit just inside their edge, 24 components darkened single scattering by 15–30%
    /// (`docs/BENCHMARKS.md`, "Local visibility at raking light"). The bits cost
    /// `svf_resolution²/8` bytes an image (72 at 24², less than the 24 coefficients' 96; 2 KB
    /// at the paper's 128²). Off: the PCA SSDF's hard and erf steps (the paper).
    #[serde(default)]
    pub visibility_bits: bool,
    /// Number Q of SGs in the sum-of-SGs visibility.
    pub sos_count: usize,
    /// Sharpness λ_svf of those SGs.
    pub sos_sharpness: f64,
    /// Target IIRTF cell side across the fabric (x, y) as a multiple of the measured mean free
    /// path ℓ.
    pub cell_size_mfp: f64,
    /// Target IIRTF cell side through the fabric (z, depth) as a multiple of ℓ: thinner than
    /// across, since transfer changes fastest with depth (`bake::cells`).
    pub cell_depth_mfp: f64,
    /// Paths traced per IIRTF cell.
    pub iirtf_paths_per_cell: usize,
    /// Light samples drawn at each fiber event of an IIRTF path (`bake::iirtf`), each carrying
    /// its share: the walk's rays are shared by all of them, and a transfer's noise comes
    /// mostly from where its few light connections land (a cell's transfer toward one light is
    /// a handful of connections near it). At 4, the interactive bake's seed-to-seed spread in
    /// multiple scattering fell by more than doubling its paths does, for less time
    /// (docs/BENCHMARKS.md, "Several light samples an event"). 1: one sample per event.
    #[serde(default = "one")]
    pub iirtf_light_samples: usize,
    /// SH order L of the IIRTF (and of C_S, C_G): (L+1)² coefficients.
    pub sh_order: usize,
    /// Number of θo values in the C_S table, equally spaced over [-π/2, π/2].
    pub cs_theta_count: usize,
    /// Voxels per mean fiber diameter along each axis of the eye-ray volume (lowered by the
    /// bake if the volume would exceed 256³ voxels; see `bake::volume`).
    pub voxels_per_fiber_diameter: f64,
    /// Rays cast to measure the mean free path.
    pub mfp_samples: usize,
    pub seed: u64,
    /// Carry the light that keeps each light's angle to the fibers outside the SH transfer,
    /// as two lobes per cell shaded in closed form against the shaded fiber's lobes
    /// (`bake::iirtf`, `shading::multiple`, `docs/MATH.md` "Fiber lobes"): the forward chains
    /// (light transmitted by every fiber on its way: a fan about the light's direction) and
    /// the light reflected at least once (a ring at the light's angle to the fibers). A cell
    /// whose forward light is broad keeps both in its matrix. Off: the paper's SH transfer
    /// holds all of it. (Read as `forward_lobe` too, its name before the ring.)
    #[serde(default, alias = "forward_lobe")]
    pub fiber_lobes: bool,
    /// IIRTF paths start at points of each cell's fibers that an eye sees (the exposed
    /// fibers, on the side facing out; `bake::iirtf::TransferSampler::exposed_start`), so a
    /// cell's transfer is the light the method's hits receive. Off: at segment midpoints, on
    /// the fiber axis (the paper), which averages in the parts of the cell under other fibers.
    #[serde(default)]
    pub exposed_starts: bool,
    /// Paths of each segment's own transfer: besides the lattice's cells, every segment an eye
    /// sees gets a cell of its own (`bake::cells` segment cells, matrices only) and is shaded
    /// with it instead of the cells interpolated around it: a cell's transfer averages the
    /// sides of a yarn a view does not see (front-lit oblique views came out 10–25 points
    /// dark, backlit ones as bright; docs/BENCHMARKS.md). Under a lattice cell that keeps
    /// fiber lobes the segment's cell holds its light reflected at least once, shaded beside
    /// the cells' forward lobes, where the fabric's reflected light fits matrices of the
    /// transfer's order (`bake::iirtf::reflected_light_fits_matrices`); otherwise such
    /// segments keep the cells' lobes alone. 0: the cells alone (the paper).
    #[serde(default)]
    pub segment_transfer_paths: usize,
    /// Radius, in mean free paths ℓ, over which each segment's own transfer is pooled with
    /// those of the seen segments of its yarn around it (`bake::iirtf::pool_segment_cells`,
    /// weights falling to zero at the radius). A segment's few dozen paths leave grain that
    /// a view does not average away; its neighbours lie on the same side of the yarn. 0: each
    /// segment keeps its own paths' transfer.
    #[serde(default)]
    pub segment_pool_mfp: f64,
}

impl Quality {
    pub const ALL: [Quality; 3] = [Quality::Draft, Quality::Interactive, Quality::Paper];

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Draft => "draft",
            Self::Interactive => "interactive",
            Self::Paper => "paper",
        }
    }

    #[must_use]
    pub fn settings(self) -> BakeSettings {
        match self {
            Self::Draft => BakeSettings {
                svf_resolution: 16,
                visibility_points: 1,
                pca_components: 8,
                visibility_bits: true,
                sos_count: 32,
                sos_sharpness: 128.0,
                cell_size_mfp: 3.0,
                cell_depth_mfp: 0.5,
                iirtf_paths_per_cell: 96,
                iirtf_light_samples: 1,
                sh_order: 2,
                cs_theta_count: 64,
                voxels_per_fiber_diameter: 1.75,
                mfp_samples: 4_000,
                seed: 1,
                fiber_lobes: true,
                exposed_starts: true,
                segment_transfer_paths: 0,
                segment_pool_mfp: 0.0,
            },
            Self::Interactive => BakeSettings {
                svf_resolution: 24,
                visibility_points: 2,
                pca_components: 24,
                visibility_bits: true,
                sos_count: 64,
                sos_sharpness: 128.0,
                cell_size_mfp: 2.5,
                cell_depth_mfp: 0.5,
                iirtf_paths_per_cell: 480,
                iirtf_light_samples: 4,
                sh_order: 4,
                cs_theta_count: 256,
                voxels_per_fiber_diameter: 2.0,
                mfp_samples: 20_000,
                seed: 1,
                fiber_lobes: true,
                exposed_starts: true,
                segment_transfer_paths: 480,
                segment_pool_mfp: 0.0,
            },
            Self::Paper => BakeSettings {
                svf_resolution: 128,
                visibility_points: 1,
                pca_components: 48,
                visibility_bits: false,
                sos_count: 48,
                sos_sharpness: 128.0,
                cell_size_mfp: 1.0,
                cell_depth_mfp: 1.0,
                iirtf_paths_per_cell: 50_000,
                iirtf_light_samples: 1,
                sh_order: 5,
                cs_theta_count: 512,
                voxels_per_fiber_diameter: 2.5,
                mfp_samples: 100_000,
                seed: 1,
                fiber_lobes: false,
                exposed_starts: false,
                segment_transfer_paths: 0,
                segment_pool_mfp: 0.0,
            },
        }
    }
}

impl BakeSettings {
    /// Paths traced in a lattice cell and in a segment cell (`bake::cells`).
    #[must_use]
    pub fn cell_paths(&self) -> CellPaths {
        CellPaths { lattice: self.iirtf_paths_per_cell, segment: self.segment_transfer_paths }
    }

    /// The SH order of the C_G table and of a light's coefficients: the transfer's, or that of
    /// the fiber lobes' strength ([`super::iirtf::LOBE_SH_ORDER`]) where it is higher.
    #[must_use]
    pub fn light_sh_order(&self) -> usize {
        if self.fiber_lobes { self.sh_order.max(super::iirtf::LOBE_SH_ORDER) } else { self.sh_order }
    }

    /// Rejects values outside the ranges the stages support, naming the knob and the range.
    pub fn validate(&self) -> Result<(), ParamError> {
        check_count("svf_resolution", self.svf_resolution, 4, 512)?;
        check_count("visibility_points", self.visibility_points, 1, MAX_VISIBILITY_POINTS)?;
        check_count("pca_components", self.pca_components, 1, 256)?;
        check_count("sos_count", self.sos_count, 1, 1024)?;
        check_range("sos_sharpness", self.sos_sharpness, 1.0, 1e4)?;
        check_range("cell_size_mfp", self.cell_size_mfp, 0.25, 64.0)?;
        check_range("cell_depth_mfp", self.cell_depth_mfp, 0.25, 64.0)?;
        check_count("iirtf_paths_per_cell", self.iirtf_paths_per_cell, 1, 100_000_000)?;
        check_count("iirtf_light_samples", self.iirtf_light_samples, 1, 64)?;
        check_count("segment_transfer_paths", self.segment_transfer_paths, 0, 100_000_000)?;
        check_range("segment_pool_mfp", self.segment_pool_mfp, 0.0, 8.0)?;
        check_count("sh_order", self.sh_order, 0, crate::sh::EULER_MAX_ORDER)?;
        check_count("cs_theta_count", self.cs_theta_count, 2, 8192)?;
        check_range(
            "voxels_per_fiber_diameter",
            self.voxels_per_fiber_diameter,
            super::volume::MIN_VOXELS_PER_DIAMETER,
            super::volume::MAX_VOXELS_PER_DIAMETER,
        )?;
        check_count("mfp_samples", self.mfp_samples, 100, 100_000_000)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_paper_matches_the_paper() {
        for q in Quality::ALL {
            q.settings().validate().unwrap();
        }
        let p = Quality::Paper.settings();
        assert_eq!((p.svf_resolution, p.pca_components, p.sos_count), (128, 48, 48));
        assert_eq!((p.iirtf_paths_per_cell, p.sh_order, p.cs_theta_count), (50_000, 5, 512));
        let mut bad = p;
        // Orders above the SH rotation's tables (and the GPU's SH_MAX_ORDER) are refused, not
        // left to panic in the shading.
        bad.sh_order = 7;
        assert!(bad.validate().unwrap_err().to_string().contains("0 <= sh_order <= 6"));
    }

    #[test]
    fn fiber_lobes_read_under_their_old_name_and_raise_the_light_sh_order() {
        let text = |key: &str| {
            let s = Quality::Interactive.settings();
            let mut table = toml::Table::try_from(s).unwrap();
            table.remove("fiber_lobes");
            table.insert(key.to_string(), toml::Value::Boolean(true));
            table.to_string()
        };
        for key in ["fiber_lobes", "forward_lobe"] {
            let s: BakeSettings = toml::from_str(&text(key)).unwrap();
            assert!(s.fiber_lobes, "{key}");
            assert_eq!(s.light_sh_order(), super::super::iirtf::LOBE_SH_ORDER);
        }
        let plain = BakeSettings { fiber_lobes: false, ..Quality::Draft.settings() };
        assert_eq!(plain.light_sh_order(), plain.sh_order);
    }
}
