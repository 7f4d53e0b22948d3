//! A baked fabric on the GPU: the bake set's tables packed into the storage buffers of bind
//! group 1, the layout `shaders/shared/fabric_data.wgsl` reads.
//!
//! How it works: every exemplar of the set is appended to one shared buffer per kind of data
//! (voxels, segments, PCA basis and coefficients, sum-of-SG weights, IIRTF, C_S, Gn), and an
//! [`ExemplarGpu`] per exemplar records where its slices start; segment and cell ids in the
//! segment table are made global the same way, and so are material ids. The C_G table is the
//! same for every exemplar (it depends only on the SH order), so the first one is used.
//!
//! Cells are stored sparsely: only a cell that holds segments has a transfer matrix, in its
//! *slot* (slots number those cells in global cell order, so each exemplar's are contiguous),
//! and `cell_slots` maps every cell of the grid to 1 + its slot, or 0 when empty. The segment
//! cells (`bake::cells`, one segment each, matrices only) are numbered after every exemplar's
//! lattice cells, so that the lobe table (below) stops at the last lattice slot. Most of a grid
//! is empty (air above and below the yarns, the gaps between them: 6,013 of the default
//! fabric's 9,025 interactive cells, 249,191 of `large`'s 269,664 at `paper`), and an empty cell
//! costs 4 bytes instead of a matrix.
//!
//! Fiber lobes are sparser still: only a lattice cell that keeps lobes has them, in its *lobe
//! slot* (numbered in slot order), and the lobes buffer opens with a table of one `u32` per
//! lattice slot, 1 + its lobe slot or 0 (`FabricArrays::lobe_slots`). A cell keeps lobes only
//! where its forward light is sharp: on the default cotton about 325 of its 3,014 lattice
//! slots, whose lobes take 6.6 MB where a lobe per slot took 61 MB of mostly zeros
//! (on the silk satin nearly every cell keeps them). A live recolouring writes the lobe slots'
//! lobes, and a cell without one its whole matrix (`Recolouring::write_cell`); where its
//! colours change which cells keep lobes, it lays the lobe slots out anew first.
//!
//! The IIRTF dominates the memory of a fabric without lobes (`slots × 3 × (L+1)⁴` values) and
//! is stored as f16 pairs: its entries carry Monte Carlo noise of a few percent, far above
//! f16's 2⁻¹¹ relative rounding, and halving it keeps the default fabric's data well inside
//! lavapipe's 128 MiB per binding. Fiber lobes (`BakeSettings::fiber_lobes`) are packed per
//! lobe slot by `CellTransfer::pack_lobes` ([`LOBE_PACKED_FLOATS`] f32s, 20,384 bytes: the
//! strengths and a shape per lobe and colour channel); a bake without them binds one zeroed
//! vec4. The C_G table is packed at its own order (`BakeSettings::light_sh_order`, which is
//! above the transfer's with fiber lobes), which the header carries (`cg_order`).
//! Every buffer is checked against the adapter's `max_storage_buffer_binding_size`
//! before upload; one that does not fit is an error naming the buffer, its size and the limit.

use glam::Vec3;
use twill_precompute::bake::iirtf::{CellTransfer, LOBE_PACKED_FLOATS, LOBE_SH_ORDER, LOBE_SHAPE_LEN};
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::Baked;

use crate::passes::{storage_entry, uniform_entry};
use twill_precompute::bcsdf::MaterialDesc;

/// Why a bake could not be placed on the GPU.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FabricDataError {
    #[error(
        "the bake's {buffer} data needs {bytes} bytes but the adapter allows {limit} bytes per storage \
         binding (max_storage_buffer_binding_size); bake at a lower quality or a smaller fabric"
    )]
    TooLarge { buffer: &'static str, bytes: u64, limit: u64 },
    #[error("the bake set is inconsistent: {0}")]
    Inconsistent(String),
    #[error("the bake set has no exemplars")]
    Empty,
    #[error(
        "exemplar {exemplar}'s material slot {slot} is Lambertian: the GPU method (Khungurn et al. 2017) \
         shades fiber (R + TT) materials only; render Lambertian yarns with `twill reference`"
    )]
    LambertMaterial { exemplar: usize, slot: usize },
}

/// Twin of `FabricHeader` in `shaders/shared/fabric_data.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FabricHeaderGpu {
    pub exemplar_count: u32,
    pub sh_order: u32,
    pub sh_count: u32,
    pub svf_resolution: u32,
    pub pca_components: u32,
    pub sos_count: u32,
    pub sos_sharpness: f32,
    pub cs_theta_count: u32,
    pub cg_points: u32,
    pub gn_intervals: u32,
    pub pattern_width: u32,
    pub pattern_height: u32,
    pub block_size: [f32; 2],
    pub z_range: [f32; 2],
    /// SH order of the C_G table (`cg_table` holds `cg_points × (cg_order + 1)` values): the
    /// transfer's `sh_order`, or [`LOBE_SH_ORDER`] when the bake has fiber lobes
    /// (`BakeSettings::light_sh_order`).
    pub cg_order: u32,
    /// Visibility points per segment (`VisibilityData::points`): `pca_coefficients` and
    /// `sum_of_sg` hold that many images per segment.
    pub visibility_points: u32,
    /// `u32` words per binary visibility image in `visibility_bits` (`BakeSettings::
    /// visibility_bits`), 0 when the bake kept none (local visibility is then the PCA SSDF's
    /// sign).
    pub visibility_words: u32,
    /// vec4s of the lobe table at the start of `lobes` ([`FabricArrays::lobes`]): one `u32` per
    /// lattice slot, four per vec4; 0 for a fabric without lobes.
    pub lobe_table_vec4s: u32,
}
const _: () = assert!(size_of::<FabricHeaderGpu>() == 80);

/// Twin of `ExemplarGpu` in `shaders/shared/fabric_data.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ExemplarGpu {
    pub volume_origin: [f32; 3],
    pub voxel_offset: u32,
    pub voxel_size: [f32; 3],
    pub periodic: u32,
    pub volume_dims: [u32; 3],
    pub segment_offset: u32,
    pub period: [f32; 2],
    pub pca_offset: u32,
    pub segment_count: u32,
    /// The IIRTF cell lattice (`bake::cells::CellGrid`): lower corner (cm).
    pub cell_origin: [f32; 3],
    /// Global id of the exemplar's first cell.
    pub cell_offset: u32,
    /// Side lengths of a cell (cm).
    pub cell_size: [f32; 3],
    /// Blocks along x.
    pub cell_blocks_x: u32,
    /// Cells per block along x, y, z.
    pub cell_dims: [u32; 3],
    /// Blocks along y. The lattice repeats across the fabric when `periodic` is set (the cell
    /// grid and the volume share the exemplar's tiling).
    pub cell_blocks_y: u32,
}
const _: () = assert!(size_of::<ExemplarGpu>() == 112);

impl ExemplarGpu {
    /// Cells in the exemplar's whole lattice: every block's (`CellGrid::lattice_cell_count`; a
    /// patterned exemplar spans several blocks). Its segment cells, if any, follow them.
    #[must_use]
    pub fn cell_count(&self) -> usize {
        self.cell_dims.iter().map(|&d| d as usize).product::<usize>()
            * self.cell_blocks_x as usize
            * self.cell_blocks_y as usize
    }
}

/// Twin of `SegmentGpu` in `shaders/shared/fabric_data.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SegmentGpu {
    pub direction: [f32; 3],
    pub material: u32,
    /// Midpoint (exemplar coordinates, cm) and half length (`SegmentTable::axis`): the
    /// capsule eye rays test, and where along the segment a shaded point lies, to pick its
    /// visibility image.
    pub midpoint: [f32; 3],
    pub half_length: f32,
    pub cell: u32,
    /// The sum-of-SGs rotation of its Fibonacci axes, shared by the segment's visibility
    /// points.
    pub sos_rotation: f32,
    /// Fiber radius (cm): the capsule eye rays test.
    pub radius: f32,
    /// Global id of the segment's own cell (`CellGrid::segment_cell`), or [`NO_SEGMENT_CELL`]
    /// where the bake has none (`BakeSettings::segment_transfer_paths` off).
    pub segment_cell: u32,
}
const _: () = assert!(size_of::<SegmentGpu>() == 48);

/// [`SegmentGpu::segment_cell`] of a segment without a cell of its own.
pub const NO_SEGMENT_CELL: u32 = u32::MAX;

/// Twin of `MaterialGpu` in `shaders/shared/fabric_data.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MaterialGpu {
    pub c_r: [f32; 3],
    pub model: u32,
    pub c_tt: [f32; 3],
    pub beta_r: f32,
    pub albedo: [f32; 3],
    pub beta_tt: f32,
    pub gamma_tt: f32,
    pub pad: [u32; 3],
}
const _: () = assert!(size_of::<MaterialGpu>() == 64);

/// `MaterialGpu::model` of the fiber model (twin of `MATERIAL_FIBER`).
pub const MATERIAL_FIBER: u32 = 0;
/// `MaterialGpu::model` of a Lambertian fiber (twin of `MATERIAL_LAMBERT`).
pub const MATERIAL_LAMBERT: u32 = 1;

/// The packed contents of every buffer of bind group 1, before upload (also what the CPU-side
/// tests inspect).
#[derive(Debug, Clone, PartialEq)]
pub struct FabricArrays {
    pub header: FabricHeaderGpu,
    pub exemplars: Vec<ExemplarGpu>,
    pub pattern: Vec<u32>,
    pub voxels: Vec<u32>,
    pub segments: Vec<SegmentGpu>,
    pub materials: Vec<MaterialGpu>,
    pub pca_basis: Vec<f32>,
    pub pca_coefficients: Vec<f32>,
    /// Per image and SG (`[image * sos_count + q]`): the weight's f32 bits and the axis
    /// (`SumOfSgVisibility::packed_axes`, two snorm16s of its octahedral map).
    pub sum_of_sg: Vec<[u32; 2]>,
    /// The binary visibility images (`VisibilityData::bits`), image after image in global
    /// image order, `header.visibility_words` words each (bit `p % 32` of word `p / 32` is
    /// pixel `p`); one zero word when the bake kept none.
    pub visibility_bits: Vec<u32>,
    /// f16 pairs, one matrix per slot (see the module doc).
    pub iirtf: Vec<u32>,
    /// Per global cell: 1 + its slot if it holds segments (and so a transfer matrix), 0 if
    /// empty. Slots number the lattice cells that hold segments in global cell order, so each
    /// exemplar's are contiguous, and then the segment cells that have a transfer
    /// (`bake::cells`), likewise.
    pub cell_slots: Vec<u32>,
    /// Slots: the cells that hold segments.
    pub slot_count: usize,
    /// The lattice cells' slots, the first ones: the only ones with fiber lobes.
    pub lattice_slot_count: usize,
    /// Per lattice slot, 1 + its *lobe slot*, or 0 for a cell that keeps no lobes at the
    /// bake's colours (it holds all of its light in its matrix). Lobe slots number the cells
    /// that keep lobes in slot order, so each exemplar's are contiguous.
    pub lobe_slots: Vec<u32>,
    /// The fiber lobes (`CellTransfer::forward`, `reflected` and their shapes), twin of `lobes`
    /// in `shaders/shared/fabric_data.wgsl`: first the lobe table, `lobe_slots` as `u32` bits
    /// (`header.lobe_table_vec4s` vec4s, zero-padded), then per lobe slot
    /// [`LOBE_PACKED_FLOATS`] floats in `CellTransfer::pack_lobes`' layout. Only the cells that
    /// keep lobes have them: on the default cotton about 325 of its 3,014 lattice slots, 6.6 MB
    /// where a lobe per slot took 61 MB of mostly zeros. Empty for a set baked without fiber
    /// lobes in which no cell has them (the buffer is then one zeroed vec4, never read).
    pub lobes: Vec<f32>,
    /// Cells whose lobes are not all zeros: the plan compiles `ENABLE_FIBER_LOBES` only when
    /// there are any (a bake made with the option whose cells all folded their light into their
    /// matrices shades without them). Counted when packed and after every recolouring, which
    /// can give a cell lobes or take them away.
    pub lobe_cells: usize,
    pub cs_table: Vec<f32>,
    pub cg_table: Vec<f32>,
    pub gn_table: Vec<f32>,
    /// The largest relative error f16 storage gave any IIRTF entry whose magnitude is at least
    /// 1e-3 of its cell's largest entry (smaller ones are noise-dominated).
    pub iirtf_f16_max_rel_error: f64,
}

fn f32s(v: Vec3) -> [f32; 3] {
    v.to_array()
}

fn material_gpu(desc: &MaterialDesc) -> MaterialGpu {
    let zero = [0.0; 3];
    match desc {
        MaterialDesc::Fiber(p) => MaterialGpu {
            c_r: f32s(p.c_r.as_vec3()),
            model: MATERIAL_FIBER,
            c_tt: f32s(p.c_tt.as_vec3()),
            beta_r: p.beta_r_deg.to_radians() as f32,
            albedo: zero,
            beta_tt: p.beta_tt_deg.to_radians() as f32,
            gamma_tt: p.gamma_tt_deg.to_radians() as f32,
            pad: [0; 3],
        },
        MaterialDesc::Lambert { albedo } => MaterialGpu {
            c_r: zero,
            model: MATERIAL_LAMBERT,
            c_tt: zero,
            beta_r: 0.0,
            albedo: f32s(albedo.as_vec3()),
            beta_tt: 0.0,
            gamma_tt: 0.0,
            pad: [0; 3],
        },
    }
}

/// The C_G table's values, then the upper-hemisphere fits (`twill_precompute::upper_fit`) of
/// every SH order up to the table's, each as `UpperHemisphereFit::packed` in f32
/// (`shaders/shared/shading.wgsl` `upper_fit_offset`).
fn cg_table_with_fits(cg: &twill_precompute::bake::tables::CgTable) -> Vec<f32> {
    let mut values = cg.values().to_vec();
    for order in 0..=cg.order() {
        let fit = twill_precompute::upper_fit::UpperHemisphereFit::of_order(order);
        values.extend(fit.packed().iter().map(|&v| v as f32));
    }
    values
}

fn to_u32(n: usize, what: &str) -> Result<u32, FabricDataError> {
    u32::try_from(n)
        .map_err(|_| FabricDataError::Inconsistent(format!("{what} = {n} does not fit in 32 bits")))
}

/// Highest SH order the shaders hold: their coefficient arrays have `SH_MAX_COUNT` =
/// (`MAX_SH_ORDER` + 1)² entries (`shaders/shared/sh.wgsl`; a test checks the two agree).
pub const MAX_SH_ORDER: usize = 6;

impl FabricArrays {
    /// Packs a bake set (its exemplars in pattern order) for the GPU.
    pub fn pack(exemplars: &[&Baked], pattern: &PatternMap) -> Result<Self, FabricDataError> {
        let first = exemplars.first().ok_or(FabricDataError::Empty)?;
        let settings = &first.settings;
        let sh_order = first.transfer.iirtf.sh_order;
        if sh_order > MAX_SH_ORDER {
            return Err(FabricDataError::Inconsistent(format!(
                "the bake's SH order is {sh_order}; the GPU renderer holds SH order {MAX_SH_ORDER} at most \
                 (bake with --set sh_order=N, N <= {MAX_SH_ORDER})"
            )));
        }
        let sh_count = (sh_order + 1) * (sh_order + 1);
        let dims = first.visibility.ssdf.dims;
        let components = first.visibility.ssdf.component_count;
        let visibility_points = first.visibility.points;
        let sos_count = first.visibility.sum_of_sg.count;
        // u32 words per kept binary image: two per u64 word of `VisibilityImages`.
        let bit_words = first.visibility.bits.as_ref().map(|b| 2 * b.words_per_image());
        let theta_count = settings.cs_theta_count;
        let mut out = Self {
            header: FabricHeaderGpu::zeroed_header(),
            exemplars: Vec::new(),
            pattern: pattern.exemplar_of_block.iter().map(|&e| u32::from(e)).collect(),
            voxels: Vec::new(),
            segments: Vec::new(),
            materials: Vec::new(),
            pca_basis: Vec::new(),
            pca_coefficients: Vec::new(),
            sum_of_sg: Vec::new(),
            visibility_bits: Vec::new(),
            iirtf: Vec::new(),
            cell_slots: Vec::new(),
            slot_count: 0,
            lattice_slot_count: 0,
            lobe_slots: Vec::new(),
            lobes: Vec::new(),
            lobe_cells: 0,
            cs_table: Vec::new(),
            cg_table: cg_table_with_fits(&first.cg),
            gn_table: Vec::new(),
            iirtf_f16_max_rel_error: 0.0,
        };
        if pattern.exemplar_count() > exemplars.len() {
            return Err(FabricDataError::Inconsistent(format!(
                "the pattern names {} exemplars but the bake has {}",
                pattern.exemplar_count(),
                exemplars.len()
            )));
        }
        let mut iirtf_values: Vec<f32> = Vec::new();
        // The lobe slots' packed lobes, after the table that `lobes` starts with.
        let mut lobe_data: Vec<f32> = Vec::new();
        let mut slots = 0_usize;
        let mut any_lobes = false;
        let mut z_range = [f32::INFINITY, f32::NEG_INFINITY];
        let mut block_size = [0.0_f32; 2];
        for (e, baked) in exemplars.iter().enumerate() {
            let same = baked.transfer.iirtf.sh_order == sh_order
                && baked.visibility.ssdf.dims == dims
                && baked.visibility.ssdf.component_count == components
                && baked.visibility.sum_of_sg.count == sos_count
                && baked.settings.cs_theta_count == theta_count
                && baked.visibility.points == visibility_points
                && baked.visibility.bits.as_ref().map(|b| 2 * b.words_per_image()) == bit_words
                && baked.volume.segments.axis.len() == baked.volume.segments.len()
                && baked.volume.segments.radius.len() == baked.volume.segments.len();
            if !same {
                return Err(FabricDataError::Inconsistent(format!(
                    "exemplar {e} was baked with different settings from exemplar 0"
                )));
            }
            let volume = &baked.volume.volume;
            let cells = &baked.transfer.cells;
            if volume.periodic != cells.is_periodic() {
                return Err(FabricDataError::Inconsistent(format!(
                    "exemplar {e}: the volume and the IIRTF cells disagree on whether the fabric tiles"
                )));
            }
            let segment_count = baked.volume.segments.len();
            let segment_offset = out.segments.len();
            let cell_base = out.cell_slots.len();
            let material_offset = out.materials.len();
            let extent = volume.voxel_size * Vec3::from(volume.dims.map(|d| d as f32));
            z_range = [z_range[0].min(volume.origin.z), z_range[1].max(volume.origin.z + extent.z)];
            let block = cells.block_size_cm();
            block_size = [block.x as f32, block.y as f32];
            out.exemplars.push(ExemplarGpu {
                volume_origin: f32s(volume.origin),
                voxel_offset: to_u32(out.voxels.len(), "voxel offset")?,
                voxel_size: f32s(volume.voxel_size),
                periodic: u32::from(volume.periodic),
                volume_dims: volume.dims,
                segment_offset: to_u32(segment_offset, "segment offset")?,
                period: [extent.x, extent.y],
                pca_offset: to_u32(out.pca_basis.len(), "PCA offset")?,
                segment_count: to_u32(segment_count, "segment count")?,
                cell_origin: f32s(cells.origin_cm().as_vec3()),
                cell_offset: to_u32(cell_base, "cell")?,
                cell_size: f32s(cells.cell_size_cm().as_vec3()),
                cell_blocks_x: cells.blocks()[0],
                cell_dims: cells.dims(),
                cell_blocks_y: cells.blocks()[1],
            });
            let lobe_sh = twill_precompute::sh::sh_count(LOBE_SH_ORDER);
            let lattice = cells.lattice_cell_count();
            for (c, cell) in baked.transfer.iirtf.cells.iter().enumerate() {
                // Only cells that hold segments get a slot: its lobes and its matrix, packed here.
                // Segment cells get theirs after every exemplar's lattice (below).
                if cell.paths == 0 || c >= lattice {
                    out.cell_slots.push(0);
                    continue;
                }
                slots += 1;
                out.cell_slots.push(to_u32(slots, "slot")?);
                let sizes = [
                    cell.forward.len(),
                    cell.reflected.len(),
                    cell.forward_shape.len(),
                    cell.reflected_shape.len(),
                ];
                if cell.has_lobes() && sizes != [lobe_sh, lobe_sh, LOBE_SHAPE_LEN, LOBE_SHAPE_LEN] {
                    return Err(FabricDataError::Inconsistent(format!(
                        "exemplar {e} cell {c}: lobes of {sizes:?} values, expected {lobe_sh}, {lobe_sh}, \
                         {LOBE_SHAPE_LEN} and {LOBE_SHAPE_LEN}"
                    )));
                }
                if cell.has_lobes() {
                    let start = lobe_data.len();
                    lobe_data.resize(start + LOBE_PACKED_FLOATS, 0.0);
                    cell.pack_lobes(&mut lobe_data[start..]);
                    out.lobe_slots.push(to_u32(start / LOBE_PACKED_FLOATS + 1, "lobe slot")?);
                } else {
                    out.lobe_slots.push(0);
                }
                push_matrix(cell, sh_count, &mut iirtf_values, &mut out.iirtf_f16_max_rel_error);
            }
            // A bake made with fiber lobes keeps its buffer even when every cell folded its light
            // into its matrix: a recolouring can give a cell lobes again.
            any_lobes |=
                baked.settings.fiber_lobes || baked.transfer.iirtf.cells.iter().any(CellTransfer::has_lobes);
            out.voxels.extend_from_slice(&volume.ids);
            for k in 0..segment_count {
                let [x, y, z, half_length] = baked.volume.segments.axis[k];
                out.segments.push(SegmentGpu {
                    direction: baked.volume.segments.direction[k],
                    material: to_u32(material_offset, "material")? + baked.volume.segments.material[k],
                    midpoint: [x, y, z],
                    half_length,
                    cell: to_u32(cell_base, "cell")? + cells.cell_of_segment(to_u32(k, "segment")?),
                    sos_rotation: baked.visibility.sum_of_sg.rotation(k * visibility_points),
                    radius: baked.volume.segments.radius[k],
                    segment_cell: match cells.segment_cell(to_u32(k, "segment")?) {
                        Some(c) => to_u32(cell_base, "cell")? + c,
                        None => NO_SEGMENT_CELL,
                    },
                });
            }
            if let Some(slot) = baked.materials.iter().position(|m| matches!(m, MaterialDesc::Lambert { .. }))
            {
                return Err(FabricDataError::LambertMaterial { exemplar: e, slot });
            }
            out.materials.extend(baked.materials.iter().map(material_gpu));
            let ssdf = &baked.visibility.ssdf;
            out.pca_basis.extend_from_slice(ssdf.mean());
            out.pca_basis.extend_from_slice(ssdf.components());
            out.pca_coefficients.extend_from_slice(ssdf.all_coefficients());
            let sos = &baked.visibility.sum_of_sg;
            out.sum_of_sg.extend(
                sos.all_weights().iter().zip(sos.all_packed_axes()).map(|(w, axis)| [w.to_bits(), *axis]),
            );
            if let Some(bits) = &baked.visibility.bits {
                if bits.resolution != settings.svf_resolution {
                    return Err(FabricDataError::Inconsistent(format!(
                        "exemplar {e}: binary visibility images of {0}x{0}, expected {1}x{1}",
                        bits.resolution, settings.svf_resolution
                    )));
                }
                // Little-endian halves: bit p % 64 of u64 word p / 64 is bit p % 32 of u32
                // word p / 32.
                out.visibility_bits.extend(bits.words().iter().flat_map(|&w| [w as u32, (w >> 32) as u32]));
            }
            for (m, table) in baked.cs_tables.iter().enumerate() {
                match table {
                    Some(t) => {
                        if t.sh_order() != sh_order || t.theta_count() != theta_count {
                            return Err(FabricDataError::Inconsistent(format!(
                                "exemplar {e} material {m}: C_S table has order {} x {} rows, expected {sh_order} x {theta_count}",
                                t.sh_order(),
                                t.theta_count()
                            )));
                        }
                        for c in t.coefficients() {
                            out.cs_table.extend(c.as_vec3().to_array());
                        }
                    }
                    None => out.cs_table.extend(std::iter::repeat_n(0.0, theta_count * sh_count * 3)),
                }
            }
            out.gn_table.extend_from_slice(baked.gn.data());
        }
        // The segment cells' slots (`bake::cells`), after every exemplar's lattice slots, so
        // that the lobes (lattice cells only: a segment cell has none) end with the lattice's.
        out.lattice_slot_count = slots;
        for (ex, baked) in out.exemplars.iter().zip(exemplars) {
            let first = ex.cell_offset as usize + baked.transfer.cells.lattice_cell_count();
            let segment_cells =
                baked.transfer.iirtf.cells.iter().skip(baked.transfer.cells.lattice_cell_count());
            for (c, cell) in segment_cells.enumerate().filter(|(_, cell)| cell.paths > 0) {
                slots += 1;
                out.cell_slots[first + c] = to_u32(slots, "slot")?;
                push_matrix(cell, sh_count, &mut iirtf_values, &mut out.iirtf_f16_max_rel_error);
            }
        }
        out.iirtf = pack_f16_pairs(&iirtf_values);
        out.slot_count = slots;
        let lobe_table_vec4s = if any_lobes { out.lobe_slots.len().div_ceil(4).max(1) } else { 0 };
        if any_lobes {
            out.lobes = out.lobe_slots.iter().map(|&s| f32::from_bits(s)).collect();
            out.lobes.resize(4 * lobe_table_vec4s, 0.0);
            out.lobes.extend_from_slice(&lobe_data);
        }
        // The C_G table gives every light's SH: at the transfer's order, and at the lobes'.
        let cg_order = first.cg.order();
        let needed = if any_lobes { sh_order.max(LOBE_SH_ORDER) } else { sh_order };
        if cg_order < needed || cg_order > MAX_SH_ORDER {
            return Err(FabricDataError::Inconsistent(format!(
                "the C_G table has SH order {cg_order}; the bake's lights need order {needed} (at most {MAX_SH_ORDER})"
            )));
        }
        out.header = FabricHeaderGpu {
            exemplar_count: to_u32(exemplars.len(), "exemplars")?,
            sh_order: to_u32(sh_order, "SH order")?,
            sh_count: to_u32(sh_count, "SH count")?,
            svf_resolution: to_u32(settings.svf_resolution, "SVF resolution")?,
            pca_components: to_u32(components, "PCA components")?,
            sos_count: to_u32(sos_count, "sum-of-SG count")?,
            sos_sharpness: first.visibility.sum_of_sg.sharpness as f32,
            cs_theta_count: to_u32(theta_count, "C_S rows")?,
            cg_points: to_u32(first.cg.points(), "C_G points")?,
            gn_intervals: to_u32(twill_precompute::bake::tables::GN_INTERVALS, "Gn intervals")?,
            pattern_width: pattern.width,
            pattern_height: pattern.height,
            block_size,
            z_range,
            cg_order: to_u32(cg_order, "C_G order")?,
            visibility_points: to_u32(visibility_points, "visibility points")?,
            visibility_words: to_u32(bit_words.unwrap_or(0), "visibility words")?,
            lobe_table_vec4s: to_u32(lobe_table_vec4s, "lobe table")?,
        };
        if out.visibility_bits.is_empty() {
            out.visibility_bits.push(0);
        }
        out.lobe_cells = out.count_lobe_cells();
        Ok(out)
    }

    /// Whether any cell carries fiber lobes now (then the frame plan compiles the shading pass
    /// with `ENABLE_FIBER_LOBES`).
    #[must_use]
    pub fn has_lobes(&self) -> bool {
        self.lobe_cells > 0
    }

    /// Whether the buffer holds lobes (the set was baked with fiber lobes, or some cell has
    /// them), so that a recolouring can write the lobe slots' lobes.
    #[must_use]
    pub fn holds_lobes(&self) -> bool {
        !self.lobes.is_empty()
    }

    /// Lays the lobe slots out anew for `wanted`, whether each lattice slot from `first_slot`
    /// on keeps lobes (one exemplar's, at a recolouring's colours): those get a lobe slot
    /// (zeros, for the recolouring to write), the others none; every other slot keeps its lobe
    /// slot's lobes. Lobe slots stay numbered in slot order.
    ///
    /// # Errors
    /// When the lobe table does not match the lattice slots, or a lobe slot lies outside the
    /// buffer.
    pub fn relayout_lobes(&mut self, first_slot: usize, wanted: &[bool]) -> Result<(), FabricDataError> {
        let table = 4 * self.header.lobe_table_vec4s as usize;
        if self.lobe_slots.len() != self.lattice_slot_count || table < self.lobe_slots.len() {
            return Err(FabricDataError::Inconsistent(
                "the lobe table does not match the lattice slots".into(),
            ));
        }
        let mut lobes = vec![0.0_f32; table];
        let mut lobe_slots = Vec::with_capacity(self.lobe_slots.len());
        for (slot, &old) in self.lobe_slots.iter().enumerate() {
            let keeps = match slot.checked_sub(first_slot).and_then(|i| wanted.get(i)) {
                Some(&keeps) => keeps,
                None => old != 0,
            };
            if !keeps {
                lobe_slots.push(0);
                continue;
            }
            let start = lobes.len();
            let own = slot.checked_sub(first_slot).is_some_and(|i| i < wanted.len());
            let kept = (old as usize).checked_sub(1).filter(|_| !own).map(|l| {
                let at = table + l * LOBE_PACKED_FLOATS;
                self.lobes.get(at..at + LOBE_PACKED_FLOATS)
            });
            match kept {
                Some(Some(values)) => lobes.extend_from_slice(values),
                Some(None) => {
                    return Err(FabricDataError::Inconsistent("a lobe slot lies outside the buffer".into()));
                }
                None => lobes.resize(start + LOBE_PACKED_FLOATS, 0.0),
            }
            lobe_slots.push(
                u32::try_from((start - table) / LOBE_PACKED_FLOATS + 1).map_err(|_| {
                    FabricDataError::Inconsistent("more lobe slots than a u32 numbers".into())
                })?,
            );
        }
        for (value, &slot) in lobes.iter_mut().zip(&lobe_slots) {
            *value = f32::from_bits(slot);
        }
        self.lobes = lobes;
        self.lobe_slots = lobe_slots;
        Ok(())
    }

    /// Cells whose lobes are not all zeros.
    fn count_lobe_cells(&self) -> usize {
        self.lobe_values().chunks_exact(LOBE_PACKED_FLOATS).filter(|c| c.iter().any(|v| *v != 0.0)).count()
    }

    /// The lobe slots' packed lobes: `lobes` after its table.
    #[must_use]
    pub fn lobe_values(&self) -> &[f32] {
        self.lobes.get(4 * self.header.lobe_table_vec4s as usize..).unwrap_or(&[])
    }

    /// Every buffer with its label and contents, in binding order (1 ..= 15).
    #[must_use]
    pub fn storage_buffers(&self) -> [(&'static str, &[u8]); 15] {
        [
            ("exemplars", bytemuck::cast_slice(&self.exemplars)),
            ("pattern", bytemuck::cast_slice(&self.pattern)),
            ("voxels", bytemuck::cast_slice(&self.voxels)),
            ("segments", bytemuck::cast_slice(&self.segments)),
            ("materials", bytemuck::cast_slice(&self.materials)),
            ("pca_basis", bytemuck::cast_slice(&self.pca_basis)),
            ("pca_coefficients", bytemuck::cast_slice(&self.pca_coefficients)),
            ("sum_of_sg", bytemuck::cast_slice(&self.sum_of_sg)),
            ("iirtf", bytemuck::cast_slice(&self.iirtf)),
            ("cs_table", bytemuck::cast_slice(&self.cs_table)),
            ("cg_table", bytemuck::cast_slice(&self.cg_table)),
            ("gn_table", bytemuck::cast_slice(&self.gn_table)),
            ("cell_slots", bytemuck::cast_slice(&self.cell_slots)),
            ("lobes", bytemuck::cast_slice(&self.lobes)),
            ("visibility_bits", bytemuck::cast_slice(&self.visibility_bits)),
        ]
    }

    /// Total bytes of all buffers.
    #[must_use]
    pub fn total_bytes(&self) -> u64 {
        self.storage_buffers().iter().map(|(_, b)| b.len() as u64).sum::<u64>()
            + size_of::<FabricHeaderGpu>() as u64
    }
}

impl FabricHeaderGpu {
    fn zeroed_header() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

/// f32 → f16 bits, round to nearest even (what `pack2x16float` does on the GPU; subnormal
/// halves flush toward zero below 2⁻²⁴).
#[must_use]
pub fn f32_to_f16_bits(x: f32) -> u16 {
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    let exponent = ((bits >> 23) & 0xff) as i32;
    let mantissa = bits & 0x007f_ffff;
    if exponent == 0xff {
        return sign | 0x7c00 | if mantissa != 0 { 0x200 } else { 0 };
    }
    let e = exponent - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        if e < -10 {
            return sign;
        }
        let m = mantissa | 0x0080_0000;
        let shift = (14 - e) as u32;
        let half = 1u32 << (shift - 1);
        let rounded = (m + half - 1 + ((m >> shift) & 1)) >> shift;
        return sign | rounded as u16;
    }
    let rounded = mantissa + 0x0fff + ((mantissa >> 13) & 1);
    if rounded & 0x0080_0000 != 0 {
        let e = e + 1;
        if e >= 0x1f {
            return sign | 0x7c00;
        }
        return sign | ((e as u16) << 10);
    }
    sign | ((e as u16) << 10) | (rounded >> 13) as u16
}

/// f16 bits → f32 (exact).
#[must_use]
pub fn f16_bits_to_f32(h: u16) -> f32 {
    let sign = u32::from(h & 0x8000) << 16;
    let exponent = u32::from((h >> 10) & 0x1f);
    let mantissa = u32::from(h & 0x3ff);
    let bits = match (exponent, mantissa) {
        (0, 0) => sign,
        (0, m) => {
            // Subnormal: normalize.
            let shift = m.leading_zeros() - 21;
            let m = (m << shift) & 0x3ff;
            sign | ((127 - 15 + 1 - shift) << 23) | (m << 13)
        }
        (0x1f, m) => sign | 0x7f80_0000 | (m << 13),
        (e, m) => sign | ((e + 127 - 15) << 23) | (m << 13),
    };
    f32::from_bits(bits)
}

fn f16_round_trip(x: f32) -> f32 {
    f16_bits_to_f32(f32_to_f16_bits(x))
}

/// Packs f32 values as f16 pairs, first value in the low half (`unpack2x16float(w).x`).
#[must_use]
pub fn pack_f16_pairs(values: &[f32]) -> Vec<u32> {
    values
        .chunks(2)
        .map(|pair| {
            let lo = u32::from(f32_to_f16_bits(pair[0]));
            let hi = pair.get(1).map_or(0, |&v| u32::from(f32_to_f16_bits(v)));
            lo | (hi << 16)
        })
        .collect()
}

/// The fabric's buffers and bind group on a device.
pub struct FabricData {
    pub arrays: FabricArrays,
    pub layout: wgpu::BindGroupLayout,
    pub bind_group: wgpu::BindGroup,
    /// Bytes of GPU memory the buffers take.
    pub gpu_bytes: u64,
    header_buffer: wgpu::Buffer,
    /// The storage buffers, in the order of [`FabricArrays::storage_buffers`].
    buffers: Vec<wgpu::Buffer>,
}

/// The layout of bind group 1 (a uniform and fifteen read-only storage buffers, visible to
/// fragment and compute stages).
#[must_use]
pub fn fabric_bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let visibility = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
    let mut entries = vec![uniform_entry(0, visibility)];
    entries.extend((1..=15).map(|binding| storage_entry(binding, visibility, true)));
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("twill.fabric.bind_group_layout"),
        entries: &entries,
    })
}

impl FabricData {
    /// Packs and uploads a bake set.
    pub fn upload(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        exemplars: &[&Baked],
        pattern: &PatternMap,
    ) -> Result<Self, FabricDataError> {
        let arrays = FabricArrays::pack(exemplars, pattern)?;
        let limit = device.limits().max_storage_buffer_binding_size;
        for (name, bytes) in arrays.storage_buffers() {
            if bytes.len() as u64 > limit {
                return Err(FabricDataError::TooLarge { buffer: name, bytes: bytes.len() as u64, limit });
            }
        }
        let layout = fabric_bind_group_layout(device);
        let header = make_buffer(
            device,
            queue,
            "twill.fabric.header",
            bytemuck::bytes_of(&arrays.header),
            wgpu::BufferUsages::UNIFORM,
        );
        let buffers: Vec<wgpu::Buffer> = arrays
            .storage_buffers()
            .iter()
            .map(|(name, bytes)| {
                make_buffer(
                    device,
                    queue,
                    &format!("twill.fabric.{name}"),
                    bytes,
                    wgpu::BufferUsages::STORAGE,
                )
            })
            .collect();
        let bind_group = fabric_bind_group(device, &layout, &header, &buffers);
        let gpu_bytes = header.size() + buffers.iter().map(wgpu::Buffer::size).sum::<u64>();
        Ok(Self { arrays, layout, bind_group, gpu_bytes, header_buffer: header, buffers })
    }

    /// Writes a bake set of the same layout into these buffers in place (`queue.write_buffer`),
    /// only the buffers whose bytes changed, keeping the bind group's layout (and so every
    /// pipeline built on it). Same layout: every buffer as long as before, but for the fiber
    /// lobes, and the same fabric slab (`z_range`, which the shell was built around); a
    /// material rebake, a recolouring or a colourway that moves no yarn has it. A rebake can
    /// change which cells keep lobes, and so the lobes buffer's length: that buffer is then
    /// made anew at its length, and the bind group with it. Returns the names of the buffers
    /// written, or `None` (nothing written) when the layout differs: then upload anew.
    ///
    /// # Errors
    /// As [`FabricArrays::pack`], and [`FabricDataError::TooLarge`] for lobes that outgrow the
    /// device's binding.
    pub fn update_in_place(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        exemplars: &[&Baked],
        pattern: &PatternMap,
    ) -> Result<Option<Vec<&'static str>>, FabricDataError> {
        let arrays = FabricArrays::pack(exemplars, pattern)?;
        let old = self.arrays.storage_buffers();
        let new = arrays.storage_buffers();
        let same_layout = arrays.header.z_range.map(f32::to_bits)
            == self.arrays.header.z_range.map(f32::to_bits)
            && old.iter().zip(&new).all(|((name, a), (_, b))| a.len() == b.len() || *name == "lobes");
        if !same_layout {
            return Ok(None);
        }
        let mut written = Vec::new();
        if bytemuck::bytes_of(&arrays.header) != bytemuck::bytes_of(&self.arrays.header) {
            queue.write_buffer(&self.header_buffer, 0, bytemuck::bytes_of(&arrays.header));
            written.push("header");
        }
        let mut remade = false;
        for ((buffer, (name, before)), (_, after)) in self.buffers.iter_mut().zip(&old).zip(&new) {
            if before.len() != after.len() {
                let limit = device.limits().max_storage_buffer_binding_size;
                if after.len() as u64 > limit {
                    return Err(FabricDataError::TooLarge { buffer: name, bytes: after.len() as u64, limit });
                }
                let usage = wgpu::BufferUsages::STORAGE;
                *buffer = make_buffer(device, queue, &format!("twill.fabric.{name}"), after, usage);
                remade = true;
                written.push(*name);
            } else if before != after && !after.is_empty() {
                let mut padded = after.to_vec();
                padded.resize(after.len().next_multiple_of(4), 0);
                queue.write_buffer(buffer, 0, &padded);
                written.push(*name);
            }
        }
        if remade {
            self.bind_group = fabric_bind_group(device, &self.layout, &self.header_buffer, &self.buffers);
            self.gpu_bytes =
                self.header_buffer.size() + self.buffers.iter().map(wgpu::Buffer::size).sum::<u64>();
        }
        self.arrays = arrays;
        Ok(Some(written))
    }
}

/// Bind group 1 of the fabric's `header` and storage `buffers` ([`fabric_bind_group_layout`]).
fn fabric_bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    header: &wgpu::Buffer,
    buffers: &[wgpu::Buffer],
) -> wgpu::BindGroup {
    let mut entries = vec![wgpu::BindGroupEntry { binding: 0, resource: header.as_entire_binding() }];
    for (i, buffer) in buffers.iter().enumerate() {
        entries.push(wgpu::BindGroupEntry { binding: i as u32 + 1, resource: buffer.as_entire_binding() });
    }
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("twill.fabric.bind_group"),
        layout,
        entries: &entries,
    })
}

/// Appends `cell`'s matrix channel-planar (`3 n²` values, n = `sh_count`; zeros for a cell
/// that keeps all of its light in fiber lobes) to `values`, raising `max_rel_error` to the
/// largest relative f16 rounding error of its entries above 1e-3 of its largest.
fn push_matrix(cell: &CellTransfer, sh_count: usize, values: &mut Vec<f32>, max_rel_error: &mut f64) {
    if cell.is_empty() {
        // A slot without a matrix transfers nothing.
        values.extend(std::iter::repeat_n(0.0, 3 * sh_count * sh_count));
        return;
    }
    let largest = cell.matrix.iter().flatten().fold(0.0_f32, |m, v| m.max(v.abs()));
    for channel in 0..3 {
        for entry in &cell.matrix {
            let value = entry[channel];
            values.push(value);
            if largest > 0.0 && value.abs() >= 1e-3 * largest {
                let (rounded, value) = (f64::from(f16_round_trip(value)), f64::from(value));
                *max_rel_error = max_rel_error.max((rounded - value).abs() / value.abs());
            }
        }
    }
}

/// Writes one cell of a recolouring: its IIRTF (f16 bits) and its fiber lobes, where it has a
/// lobe slot ([`Recolouring::write_cell`]).
pub type WriteRecolouredCell<'a> = dyn Fn(usize, &mut [u16], Option<&mut [f32]>) + Sync + 'a;

/// A recolouring of one exemplar, ready to write ([`FabricData::write_recolouring`]).
pub struct Recolouring<'a> {
    /// The exemplar (pattern order).
    pub exemplar: usize,
    /// The exemplar's material slots at their new colours.
    pub materials: &'a [MaterialDesc],
    /// The exemplar's C_S tables at the new colours (`None` for Lambertian slots).
    pub cs_tables: &'a [Option<twill_precompute::bake::cs_table::CsTable>],
    /// Writes cell `c`'s IIRTF as f16 bits, channel-planar (`3 n²` values: what
    /// `RecolourBasis::write_planar` writes, converted), into the first slice it is given, and
    /// its fiber lobes ([`LOBE_PACKED_FLOATS`] floats, `CellTransfer::pack_lobes`' layout, zeros
    /// for a cell that folds them into its matrix) into the second where the cell has a lobe
    /// slot; both from one evaluation of the cell (`RecolourBasis::write_cell`: one decision
    /// whether the cell keeps lobes at the new colours). A cell without a lobe slot (it folds
    /// its lobes at the new colours, `keeps_lobes`, or the fabric holds none) gets `None` and
    /// writes its whole matrix. Called for every cell of
    /// the exemplar that holds segments (the cells with a slot), in parallel.
    pub write_cell: &'a WriteRecolouredCell<'a>,
    /// Whether cell `c` keeps fiber lobes at the new colours (`RecolourBasis::keeps_lobes_at`):
    /// where the cells that keep them change, the lobe slots are laid out anew first, so that
    /// every such cell has one (as a rebake at these colours would give it).
    pub keeps_lobes: &'a (dyn Fn(usize) -> bool + Sync + 'a),
}

impl FabricData {
    /// Writes a recolouring into the buffers in place: the exemplar's materials, C_S rows,
    /// IIRTF cells (as f16, written straight into the packed array by `write_cell`) and, when
    /// the fabric holds them, fiber lobes; nothing else, but where the new colours change
    /// which cells keep lobes: then the lobe slots are laid out anew, in a new lobes buffer and
    /// bind group. Returns the buffers written.
    ///
    /// # Errors
    /// When the recolouring does not fit the exemplar's slots in the buffers.
    pub fn write_recolouring(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        r: &Recolouring<'_>,
    ) -> Result<Vec<&'static str>, FabricDataError> {
        use rayon::prelude::*;
        let (materials_buffer, cs_buffer, iirtf_buffer, lobes_buffer) = (
            self.buffer("materials").clone(),
            self.buffer("cs_table").clone(),
            self.buffer("iirtf").clone(),
            self.buffer("lobes").clone(),
        );
        let cell_slots_buffer = self.buffer("cell_slots").clone();
        let a = &mut self.arrays;
        let exemplars = a.exemplars.len();
        let slots = a.materials.len() / exemplars.max(1);
        let sh_count = a.header.sh_count as usize;
        let theta_count = a.header.cs_theta_count as usize;
        let cell_values = 3 * sh_count * sh_count;
        let Some(ex) = a.exemplars.get(r.exemplar) else {
            return Err(FabricDataError::Inconsistent(format!("no exemplar {} to recolour", r.exemplar)));
        };
        // The exemplar's cells: its lattice's, then its segment cells if it has them, up to the
        // next exemplar's first cell.
        let first_cell = ex.cell_offset as usize;
        let end_cell =
            a.exemplars.get(r.exemplar + 1).map_or(a.cell_slots.len(), |next| next.cell_offset as usize);
        let cells = end_cell.saturating_sub(first_cell);
        if r.materials.len() != slots || r.cs_tables.len() != slots || a.materials.len() != slots * exemplars
        {
            return Err(FabricDataError::Inconsistent(format!(
                "a recolouring of {} slots for an exemplar of {slots}",
                r.materials.len()
            )));
        }
        let mut written = Vec::new();
        // Materials.
        let materials: Vec<MaterialGpu> = r.materials.iter().map(material_gpu).collect();
        let slot_range = r.exemplar * slots..(r.exemplar + 1) * slots;
        if a.materials[slot_range.clone()] != materials[..] {
            a.materials[slot_range.clone()].copy_from_slice(&materials);
            let size = std::mem::size_of::<MaterialGpu>();
            let bytes = bytemuck::cast_slice(&a.materials[slot_range.clone()]);
            queue.write_buffer(&materials_buffer, (slot_range.start * size) as u64, bytes);
            written.push("materials");
        }
        // C_S rows.
        let row_values = theta_count * sh_count * 3;
        let mut cs = Vec::with_capacity(slots * row_values);
        for table in r.cs_tables {
            match table {
                Some(t) if t.sh_order() == a.header.sh_order as usize && t.theta_count() == theta_count => {
                    cs.extend(t.coefficients().iter().flat_map(|c| c.as_vec3().to_array()));
                }
                Some(_) => {
                    return Err(FabricDataError::Inconsistent(
                        "a recoloured C_S table of another size".into(),
                    ));
                }
                None => cs.extend(std::iter::repeat_n(0.0, row_values)),
            }
        }
        let cs_range = r.exemplar * slots * row_values..(r.exemplar + 1) * slots * row_values;
        a.cs_table[cs_range.clone()].copy_from_slice(&cs);
        queue.write_buffer(&cs_buffer, (cs_range.start * 4) as u64, bytemuck::cast_slice(&cs));
        written.push("cs_table");
        // The recolouring basis holds the lattice's cells alone (`RecolourBasis::segment_cells`):
        // the exemplar's segment cells (after its lattice's) lose their slots, so that their
        // segments take the lattice's cells at the new colours, until a rebake's upload gives
        // them back.
        let lattice = ex.cell_count().min(cells);
        let Some(segment_slots) = a.cell_slots.get_mut(first_cell + lattice..first_cell + cells) else {
            return Err(FabricDataError::Inconsistent("the exemplar's cells lie outside the buffer".into()));
        };
        if segment_slots.iter().any(|&slot| slot != 0) {
            segment_slots.fill(0);
            let offset = ((first_cell + lattice) * 4) as u64;
            queue.write_buffer(&cell_slots_buffer, offset, bytemuck::cast_slice(segment_slots));
            written.push("cell_slots");
        }
        // IIRTF cells, as f16 halves written into the packed pairs; sent on whole words. The
        // exemplar's lattice cells with segments have contiguous slots, in cell order.
        let exemplar_slots = &a.cell_slots[first_cell..first_cell + lattice];
        let occupied: Vec<usize> = (0..lattice).filter(|&c| exemplar_slots[c] != 0).collect();
        let Some(&first_occupied) = occupied.first() else {
            return Ok(written);
        };
        let (first_slot, filled) = (exemplar_slots[first_occupied] as usize - 1, occupied.len());
        // The cells that keep lobes at the new colours get lobe slots, the others none.
        let mut lobes_remade = false;
        if !a.lobes.is_empty() {
            let wanted: Vec<bool> = occupied.par_iter().map(|&c| (r.keeps_lobes)(c)).collect();
            let Some(own) = a.lobe_slots.get(first_slot..first_slot + filled) else {
                return Err(FabricDataError::Inconsistent(
                    "the exemplar's lobe table lies outside the buffer".into(),
                ));
            };
            if own.iter().zip(&wanted).any(|(&slot, &keeps)| (slot != 0) != keeps) {
                a.relayout_lobes(first_slot, &wanted)?;
                lobes_remade = true;
            }
        }
        let start = first_slot * cell_values;
        let halves: &mut [u16] = bytemuck::cast_slice_mut(&mut a.iirtf);
        let Some(exemplar_halves) = halves.get_mut(start..start + filled * cell_values) else {
            return Err(FabricDataError::Inconsistent(
                "the exemplar's IIRTF cells lie outside the buffer".into(),
            ));
        };
        // The exemplar's lobe slots, contiguous: each of its slots that has one writes its
        // lobes there; the others write their whole matrix (`Recolouring::write_cell`).
        let table = 4 * a.header.lobe_table_vec4s as usize;
        let with_lobes = !a.lobes.is_empty(); // holds_lobes(), while a.iirtf is borrowed
        let own_lobe_slots: Vec<u32> = if with_lobes {
            a.lobe_slots.get(first_slot..first_slot + filled).map(<[u32]>::to_vec).ok_or_else(|| {
                FabricDataError::Inconsistent("the exemplar's lobe table lies outside the buffer".into())
            })?
        } else {
            vec![0; filled]
        };
        let first_lobe = own_lobe_slots.iter().copied().find(|&l| l != 0).map_or(0, |l| l as usize - 1);
        let lobe_count = own_lobe_slots.iter().filter(|&&l| l != 0).count();
        let lobe_range =
            table + first_lobe * LOBE_PACKED_FLOATS..table + (first_lobe + lobe_count) * LOBE_PACKED_FLOATS;
        let Some(lobe_values) = a.lobes.get_mut(lobe_range.clone()) else {
            return Err(FabricDataError::Inconsistent(
                "the exemplar's fiber lobes lie outside the buffer".into(),
            ));
        };
        let mut lobe_chunks = lobe_values.chunks_exact_mut(LOBE_PACKED_FLOATS);
        let per_cell: Vec<Option<&mut [f32]>> =
            own_lobe_slots.iter().map(|&l| if l == 0 { None } else { lobe_chunks.next() }).collect();
        exemplar_halves
            .par_chunks_mut(cell_values)
            .zip(per_cell)
            .enumerate()
            .for_each(|(i, (out, lobe))| (r.write_cell)(occupied[i], out, lobe));
        let (word_start, word_end) = (start / 2, (start + filled * cell_values).div_ceil(2));
        queue.write_buffer(
            &iirtf_buffer,
            (word_start * 4) as u64,
            bytemuck::cast_slice(&a.iirtf[word_start..word_end]),
        );
        written.push("iirtf");
        if lobes_remade {
            a.lobe_cells = a.count_lobe_cells();
            let index = a.storage_buffers().iter().position(|(n, _)| *n == "lobes").expect("a lobes buffer");
            let bytes: &[u8] = bytemuck::cast_slice(&a.lobes);
            let limit = device.limits().max_storage_buffer_binding_size;
            if bytes.len() as u64 > limit {
                return Err(FabricDataError::TooLarge { buffer: "lobes", bytes: bytes.len() as u64, limit });
            }
            self.buffers[index] =
                make_buffer(device, queue, "twill.fabric.lobes", bytes, wgpu::BufferUsages::STORAGE);
            self.bind_group = fabric_bind_group(device, &self.layout, &self.header_buffer, &self.buffers);
            self.gpu_bytes =
                self.header_buffer.size() + self.buffers.iter().map(wgpu::Buffer::size).sum::<u64>();
            written.push("lobes");
        } else if lobe_count > 0 {
            let lobes = &a.lobes[lobe_range.clone()];
            queue.write_buffer(&lobes_buffer, (lobe_range.start * 4) as u64, bytemuck::cast_slice(lobes));
            written.push("lobes");
            a.lobe_cells = a.count_lobe_cells();
        }
        Ok(written)
    }

    /// The storage buffer named `name` (one of [`FabricArrays::storage_buffers`]).
    fn buffer(&self, name: &str) -> &wgpu::Buffer {
        let index =
            self.arrays.storage_buffers().iter().position(|(n, _)| *n == name).expect("a fabric buffer");
        &self.buffers[index]
    }
}

#[must_use]
/// A buffer holding `bytes` (at least 16 bytes, padded to a multiple of 4, so empty arrays
/// still bind).
pub fn make_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    label: &str,
    bytes: &[u8],
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    let size = (bytes.len() as u64).max(16).next_multiple_of(16);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: usage | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    if !bytes.is_empty() {
        let mut padded = bytes.to_vec();
        padded.resize(bytes.len().next_multiple_of(4), 0);
        queue.write_buffer(&buffer, 0, &padded);
    }
    buffer
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sh_limit_matches_the_shaders_arrays() {
        let count = (MAX_SH_ORDER + 1) * (MAX_SH_ORDER + 1);
        assert!(
            crate::shaders::SH.contains(&format!("const SH_MAX_COUNT: u32 = {count}u;")),
            "shaders/shared/sh.wgsl's SH_MAX_COUNT must be (MAX_SH_ORDER + 1)^2 = {count}"
        );
    }

    #[test]
    fn f16_round_trip_matches_ieee_half() {
        for &(x, bits) in &[
            (0.0_f32, 0x0000_u16),
            (1.0, 0x3c00),
            (-2.0, 0xc000),
            (65504.0, 0x7bff),
            (1e6, 0x7c00),
            (6.103_515_6e-5, 0x0400),
            (5.960_464_5e-8, 0x0001),
            (0.333_333_34, 0x3555),
        ] {
            assert_eq!(f32_to_f16_bits(x), bits, "{x}");
            if bits != 0x7c00 && bits != 0x3555 {
                assert!(f16_bits_to_f32(bits).to_bits() == x.to_bits(), "{bits:#x}");
            }
        }
        // Relative error of normal halves is at most 2^-11.
        for i in 0..10_000 {
            let x = 1e-4_f32 * 1.001_f32.powi(i);
            let r = f16_round_trip(x);
            assert!(((r - x) / x).abs() <= 1.0 / 2048.0 + 1e-7, "{x} -> {r}");
        }
    }
}
