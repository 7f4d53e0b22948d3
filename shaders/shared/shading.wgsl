// Render-time shading from bake data (paper 5.2, 5.3, Appendix A). Twins of
// precompute/src/shading/ (bcsdf.rs: fiber_eval_cos; gamma.rs: gamma, LobeAngles,
// lobe_quadrature; visibility.rs: ssdf_lookup, erf_soft_visibility, sum_of_sg_path,
// bits_lookup; bake/pipeline.rs: VisibilityData::visibility, soft_visibility; single.rs;
// multiple.rs: light_sh, multiple_scattering_in_cell, FiberLobe, lobe_scattering), compared on
// the GPU by renderer/tests/gpu_shading_parity.rs.
// Every direction is a unit vector in flat-fabric space; `e` is the exemplar, `segment` the
// global segment id.
#import shared/special.wgsl
#import shared/sg.wgsl
#import shared/sh.wgsl
#import shared/fabric_data.wgsl

const LOBE_R: u32 = 0u;
const LOBE_TT: u32 = 1u;
const HALF_PI: f32 = 1.5707963267948966;
// A light as the passes that shade read it. Twin: renderer/src/passes/shade.rs (LightGpu).
const LIGHT_DIRECTIONAL: u32 = 0u;
const LIGHT_SG: u32 = 1u;

struct LightGpu {
    // Unit direction toward the light (world).
    direction: vec3<f32>,
    kind: u32,
    // Irradiance (directional) or intensity (SG), linear RGB.
    color: vec3<f32>,
    sharpness: f32,
    // Shadow/visibility layer, or -1 when the light is unoccluded.
    layer: i32,
    // Weights of the sum-of-SGs and erf-SSDF paths (they add to 1).
    w_sum_of_sg: f32,
    w_ssdf_erf: f32,
    _pad: f32,
}

// A world vector `v` in a tetrahedron's flat-fabric frame, normalized: rows `m` of its world ->
// (u, v, w) map, `h` the fabric slab's thickness in cm (w spans it).
fn to_fabric_frame(m: array<vec4<f32>, 3>, h: f32, v: vec3<f32>) -> vec3<f32> {
    return normalize(vec3<f32>(dot(m[0].xyz, v), dot(m[1].xyz, v), h * dot(m[2].xyz, v)));
}

// |w - (w.t) t| at or below which w lies along +-t and has no azimuth: perpendicular(t) is used
// (bake::cs_table::AZIMUTH_MIN_PERP; f32 rounding alone leaves up to ~2e-7).
const AZIMUTH_MIN_PERP: f32 = 1e-6;

// Gn(mu) of a material's lobe by cubic Hermite interpolation (bake::tables::GnTable::eval).
fn gn_eval(material: u32, lobe: u32, mu: f32) -> f32 {
    let intervals = fabric.gn_intervals;
    let base = (material * 2u + lobe) * 2u * (intervals + 1u);
    let step = HALF_PI / f32(intervals);
    let x = min(abs(mu), HALF_PI) / step;
    let k = min(u32(x), intervals - 1u);
    let t = x - f32(k);
    let p0 = gn_table[base + 2u * k];
    let d0 = gn_table[base + 2u * k + 1u] * step;
    let p1 = gn_table[base + 2u * k + 2u];
    let d1 = gn_table[base + 2u * k + 3u] * step;
    let t2 = t * t;
    let t3 = t2 * t;
    return (2.0 * t3 - 3.0 * t2 + 1.0) * p0 + (t3 - 2.0 * t2 + t) * d0 + (-2.0 * t3 + 3.0 * t2) * p1 + (t3 - t2) * d1;
}

// The fiber model's constants of one material (shading::bcsdf::FiberConstants).
struct FiberConstants {
    c_r: vec3<f32>,
    c_tt: vec3<f32>,
    lambda_r: f32,
    lambda_tt: f32,
    kappa: f32,
    i0e_kappa: f32,
    material: u32,
}

fn fiber_constants(material: u32) -> FiberConstants {
    let m = materials[material];
    var f: FiberConstants;
    f.c_r = m.c_r;
    f.c_tt = m.c_tt;
    f.lambda_r = 0.5 / (m.beta_r * m.beta_r);
    f.lambda_tt = 0.5 / (m.beta_tt * m.beta_tt);
    f.kappa = 1.0 / (m.gamma_tt * m.gamma_tt);
    f.i0e_kappa = i0e_f32(f.kappa);
    f.material = material;
    return f;
}

fn fresnel(f: FiberConstants, cos_theta: f32) -> vec3<f32> {
    let x = 1.0 - clamp(cos_theta, 0.0, 1.0);
    let m = x * x * x * x * x;
    return f.c_r + (vec3<f32>(1.0) - f.c_r) * m;
}

// Any unit vector perpendicular to t (sg::frame_from_z(t).0).
fn perpendicular(z: vec3<f32>) -> vec3<f32> {
    let sign = select(-1.0, 1.0, z.z >= 0.0);
    let a = -1.0 / (sign + z.z);
    return vec3<f32>(1.0 + sign * z.x * z.x * a, sign * z.x * z.y * a, -sign * z.x);
}

// The part of w across the unit tangent t, w - (w.t) t (the twins' form), computed as
// (t x w) x t. In f32 the subtraction cancels near +-t: for w = t it leaves up to 2.7e-7
// (measured on lavapipe over the default fabric's tangents), and near the fiber axis
// S cos(theta_i) grows like |w_perp| / Gn(-+pi/2), so fiber_eval_cos gave up to 6.4e-3 where
// the answer is 0. The cross product of equal or opposite vectors is exactly 0 (a fused
// multiply-add would leave its product's rounding, ~1e-8).
fn across_fiber(t: vec3<f32>, w: vec3<f32>) -> vec3<f32> {
    return cross(cross(t, w), t);
}

// S(wi, wo) cos(theta_i) (shading::bcsdf::fiber_eval_cos).
fn fiber_eval_cos(f: FiberConstants, t: vec3<f32>, wi: vec3<f32>, wo: vec3<f32>) -> vec3<f32> {
    let si = dot(wi, t);
    let pi_ = across_fiber(t, wi);
    let ci = length(pi_);
    let azi = select(perpendicular(t), pi_ / ci, ci > AZIMUTH_MIN_PERP);
    let so = dot(wo, t);
    let po = across_fiber(t, wo);
    let co = length(po);
    let azo = select(perpendicular(t), po / co, co > AZIMUTH_MIN_PERP);
    let theta_i = atan2(si, ci);
    let theta_o = atan2(so, co);
    let sum = theta_i + theta_o;
    let m_r = sqrt(f.lambda_r / PI) * exp(-f.lambda_r * sum * sum) / gn_eval(f.material, LOBE_R, -theta_i);
    let m_tt = sqrt(f.lambda_tt / PI) * exp(-f.lambda_tt * sum * sum) / gn_eval(f.material, LOBE_TT, -theta_i);
    let s = azi + azo;
    let one_plus_cos = 0.5 * dot(s, s);
    let n_tt = exp(-f.kappa * one_plus_cos) / (2.0 * PI * f.i0e_kappa);
    let fr = fresnel(f, ci);
    return (fr * (m_r / (2.0 * PI)) + (vec3<f32>(1.0) - fr) * f.c_tt * (m_tt * n_tt)) * ci;
}

// The omega_o-space of a fiber (bake::cs_table::OmegaOSpace): rows t, b, c.
struct OmegaOSpace {
    t: vec3<f32>,
    b: vec3<f32>,
    c: vec3<f32>,
    theta_o: f32,
}

fn omega_o_space(t: vec3<f32>, wo: vec3<f32>) -> OmegaOSpace {
    let along = clamp(dot(wo, t), -1.0, 1.0);
    let perp = across_fiber(t, wo);
    let len = length(perp);
    var s: OmegaOSpace;
    s.t = t;
    s.b = select(perpendicular(t), perp / len, len > AZIMUTH_MIN_PERP);
    s.c = cross(t, s.b);
    s.theta_o = atan2(along, len);
    return s;
}

// Gaussian lobe of one BCSDF lobe times the SG's longitudinal profile (gamma.rs lobe_gaussian):
// x = centre, y = weight.
fn lobe_gaussian(lambda_lobe: f32, lambda: f32, theta_o: f32, theta_axis: f32) -> vec2<f32> {
    let half = 0.5 * lambda;
    let sharpness = lambda_lobe + half;
    let centre = clamp((-lambda_lobe * theta_o + half * theta_axis) / sharpness, -HALF_PI, HALF_PI);
    let sum = theta_o + theta_axis;
    let log_a = -(lambda_lobe * half / sharpness) * sum * sum;
    let s = sqrt(sharpness);
    let e = 0.5 * sqrt(PI / sharpness) * (erf_f32(s * (HALF_PI - centre)) + erf_f32(s * (HALF_PI + centre)));
    return vec2<f32>(centre, exp(log_a) * e);
}

// The SG axis xi seen from omega_o-space (gamma.rs AxisInOmegaOSpace): theta' and h = cos theta',
// and h +- xi_b without cancellation.
struct SgAxis {
    theta: f32,
    h: f32,
    h_plus_b: f32,
    h_minus_b: f32,
}

fn sg_axis_in_omega_o_space(space: OmegaOSpace, xi: vec3<f32>) -> SgAxis {
    let local = vec3<f32>(dot(space.t, xi), dot(space.b, xi), dot(space.c, xi));
    let b = local.y;
    let c = local.z;
    var axis: SgAxis;
    axis.h = sqrt(b * b + c * c);
    // (h + b)(h - b) = c^2: the larger factor directly, the smaller from it.
    if (b >= 0.0) {
        axis.h_plus_b = axis.h + b;
        axis.h_minus_b = select(0.0, c * c / axis.h_plus_b, axis.h_plus_b > 0.0);
    } else {
        axis.h_minus_b = axis.h - b;
        axis.h_plus_b = c * c / axis.h_minus_b;
    }
    axis.theta = atan2(local.x, axis.h);
    return axis;
}

// The TT azimuthal factor i0e(lambda_m) e^(lambda_m - a - kappa) / i0e(kappa) at cos(theta_i)
// (gamma.rs tt_azimuthal).
fn tt_azimuthal(f: FiberConstants, lambda: f32, cos_theta_i: f32, axis: SgAxis) -> f32 {
    let a = lambda * cos_theta_i * axis.h;
    let scale = 2.0 * f.kappa * lambda * cos_theta_i;
    let lambda_m = sqrt((a - f.kappa) * (a - f.kappa) + scale * axis.h_minus_b);
    let deficit = -scale * axis.h_plus_b / (lambda_m + a + f.kappa);
    return i0e_f32(lambda_m) * exp(deficit) / f.i0e_kappa;
}

// Gamma(xi, lambda, wo): the convolution of an unnormalized SG with S cos(theta_i) (gamma.rs).
fn sg_bcsdf_gamma(f: FiberConstants, space: OmegaOSpace, xi: vec3<f32>, lambda: f32) -> vec3<f32> {
    let axis = sg_axis_in_omega_o_space(space, xi);

    let r = lobe_gaussian(f.lambda_r, lambda, space.theta_o, axis.theta);
    let cos_r = max(cos(r.x), 0.0);
    let b_r = cos_r * cos_r * sqrt(f.lambda_r / PI) / gn_eval(f.material, LOBE_R, -r.x) * i0e_f32(lambda * cos_r * axis.h);

    let tt = lobe_gaussian(f.lambda_tt, lambda, space.theta_o, axis.theta);
    let cos_tt = max(cos(tt.x), 0.0);
    let b_tt = cos_tt * cos_tt * sqrt(f.lambda_tt / PI) / gn_eval(f.material, LOBE_TT, -tt.x) * tt_azimuthal(f, lambda, cos_tt, axis);

    return fresnel(f, cos_r) * (r.y * b_r) + (vec3<f32>(1.0) - fresnel(f, cos_tt)) * f.c_tt * (tt.y * b_tt);
}

// The visibility image that shades `segment` at exemplar-local point p (pipeline.rs
// Baked::visibility_image, svf.rs visibility_point_of): that of the visibility point whose
// piece of the segment holds p's projection on its axis, p taken in the copy of a periodic
// exemplar nearest the segment.
fn visibility_image(e: u32, segment: u32, p: vec3<f32>) -> u32 {
    let points = fabric.visibility_points;
    if (points <= 1u) {
        return segment;
    }
    let s = segments[segment];
    let ex = exemplars[e];
    var offset = p - s.midpoint;
    if (ex.periodic != 0u) {
        offset = vec3<f32>(offset.xy - ex.period * round(offset.xy / ex.period), offset.z);
    }
    let u = 0.5 + dot(offset, normalize(s.direction)) / (2.0 * s.half_length);
    var point = points / 2u;
    if (s.half_length > 0.0 && abs(u) < 1e30) {
        point = u32(clamp(floor(u * f32(points)), 0.0, f32(points - 1u)));
    }
    return segment * points + point;
}

// One pixel of a visibility image's PCA-reconstructed SSDF.
fn ssdf_pixel(e: u32, image: u32, pixel: u32) -> f32 {
    let base = exemplars[e].pca_offset;
    let dims = fabric.svf_resolution * fabric.svf_resolution;
    let k = fabric.pca_components;
    var d = pca_basis[base + pixel];
    for (var c = 0u; c < k; c++) {
        d += pca_coefficients[image * k + c] * pca_basis[base + (1u + c) * dims + pixel];
    }
    return d;
}

// The four pixels (row-major) around a unit direction and its weights, bilinear over pixel
// centres, phi wrapping, theta clamped (visibility.rs bilinear_over_pixel_centres).
struct PixelBilinear {
    p00: u32,
    p01: u32,
    p10: u32,
    p11: u32,
    fu: f32,
    fv: f32,
}

fn pixel_bilinear(dir: vec3<f32>) -> PixelBilinear {
    let n = fabric.svf_resolution;
    let nf = f32(n);
    let theta = atan2(length(dir.xy), dir.z);
    var phi = atan2(dir.y, dir.x);
    if (dir.x == 0.0 && dir.y == 0.0) {
        // At the poles WGSL leaves atan2(0, 0) undefined (lavapipe gives +-3 pi / 4, another
        // pair of columns); take the twin's IEEE f64 value: pi for x = -0, else +-0.
        phi = select(0.0, PI, (bitcast<u32>(dir.x) & 0x80000000u) != 0u);
    }
    if (phi < 0.0) {
        phi += 2.0 * PI;
    }
    let u = clamp(theta * nf / PI - 0.5, 0.0, nf - 1.0);
    let v = phi * nf / (2.0 * PI) - 0.5;
    let r0 = min(u32(floor(u)), n - 2u);
    let r1 = min(r0 + 1u, n - 1u);
    let v0 = floor(v);
    let c0 = u32(wrap_i32(i32(v0), i32(n)));
    let c1 = (c0 + 1u) % n;
    return PixelBilinear(r0 * n + c0, r0 * n + c1, r1 * n + c0, r1 * n + c1, u - f32(r0), v - v0);
}

fn bilinear_blend(b: PixelBilinear, d00: f32, d01: f32, d10: f32, d11: f32) -> f32 {
    return (1.0 - b.fu) * ((1.0 - b.fv) * d00 + b.fv * d01) + b.fu * ((1.0 - b.fv) * d10 + b.fv * d11);
}

// The SSDF at a direction (visibility.rs ssdf_lookup).
fn ssdf_lookup(e: u32, image: u32, dir: vec3<f32>) -> f32 {
    let b = pixel_bilinear(dir);
    return bilinear_blend(b, ssdf_pixel(e, image, b.p00), ssdf_pixel(e, image, b.p01),
        ssdf_pixel(e, image, b.p10), ssdf_pixel(e, image, b.p11));
}

// One pixel of a kept binary visibility image: 1 visible, 0 occluded.
fn visibility_bit(image: u32, pixel: u32) -> f32 {
    let word = visibility_bits[image * fabric.visibility_words + pixel / 32u];
    return f32((word >> (pixel % 32u)) & 1u);
}

// The kept binary image's visible fraction toward a direction (visibility.rs bits_lookup).
fn bits_lookup(image: u32, dir: vec3<f32>) -> f32 {
    let b = pixel_bilinear(dir);
    return bilinear_blend(b, visibility_bit(image, b.p00), visibility_bit(image, b.p01),
        visibility_bit(image, b.p10), visibility_bit(image, b.p11));
}

// Local visibility toward a directional light: the kept binary image's visible fraction, else
// the PCA SSDF's hard step (pipeline.rs VisibilityData::visibility).
fn local_visibility(e: u32, image: u32, dir: vec3<f32>) -> f32 {
    if (fabric.visibility_words > 0u) {
        return bits_lookup(image, dir);
    }
    return select(0.0, 1.0, ssdf_lookup(e, image, dir) > 0.0);
}

// Local visibility for a sharp SG light: the kept binary image's visible fraction toward its
// axis, else the PCA SSDF's erf step (pipeline.rs VisibilityData::soft_visibility).
fn local_soft_visibility(e: u32, image: u32, axis: vec3<f32>, lambda: f32) -> f32 {
    if (fabric.visibility_words > 0u) {
        return bits_lookup(image, axis);
    }
    return 0.5 * erfc_f32(-sqrt(0.5 * lambda) * ssdf_lookup(e, image, axis));
}

// Single scattering of a unit-irradiance directional light (single.rs): local visibility
// times S cos(theta_d).
fn shade_single_directional(e: u32, segment: u32, image: u32, wo: vec3<f32>, wd: vec3<f32>) -> vec3<f32> {
    let local = local_visibility(e, image, wd);
    if (local <= 0.0) {
        return vec3<f32>(0.0);
    }
    let s = segments[segment];
    return fiber_eval_cos(fiber_constants(s.material), normalize(s.direction), wd, wo) * local;
}

// Single scattering of a unit-intensity normalized SG light through the erf-smoothed SSDF.
fn shade_single_sg_ssdf_erf(e: u32, segment: u32, image: u32, wo: vec3<f32>, axis: vec3<f32>, lambda: f32) -> vec3<f32> {
    let soft = local_soft_visibility(e, image, axis, lambda);
    if (soft <= 0.0) {
        return vec3<f32>(0.0);
    }
    let s = segments[segment];
    let space = omega_o_space(normalize(s.direction), wo);
    return sg_bcsdf_gamma(fiber_constants(s.material), space, axis, lambda) * (soft / sg_mass_f32(lambda));
}

// A unit vector from two snorm16s of its octahedral map (sum_of_sg.rs unpack_unit_vector).
fn unpack_unit_vector(bits: u32) -> vec3<f32> {
    let p = unpack2x16snorm(bits);
    let z = 1.0 - abs(p.x) - abs(p.y);
    let sign = select(vec2<f32>(-1.0), vec2<f32>(1.0), p >= vec2<f32>(0.0));
    let xy = select((1.0 - abs(p.yx)) * sign, p, z >= 0.0);
    return normalize(vec3<f32>(xy, z));
}

// Single scattering of a unit-intensity normalized SG light through the sum-of-SGs visibility
// (visibility.rs sum_of_sg_path): each visibility SG times the light is one sharper SG.
fn shade_single_sg_sum_of_sg(e: u32, segment: u32, image: u32, wo: vec3<f32>, axis: vec3<f32>, lambda: f32) -> vec3<f32> {
    let s = segments[segment];
    let f = fiber_constants(s.material);
    let space = omega_o_space(normalize(s.direction), wo);
    let q_count = fabric.sos_count;
    let lambda_svf = fabric.sos_sharpness;
    let inv_mass = 1.0 / sg_mass_f32(lambda_svf);
    let centroid_share = sos_centroid_share(lambda, q_count);
    let rot = vec2<f32>(cos(s.sos_rotation), sin(s.sos_rotation));
    var total = vec3<f32>(0.0);
    for (var q = 0u; q < q_count; q++) {
        let sg = sum_of_sg[image * q_count + q];
        let w = bitcast<f32>(sg.x);
        if (w == 0.0) {
            continue;
        }
        // The SG at the centroid of the visible directions it holds (sum_of_sg.rs) for lights
        // broader than a cell, at its Fibonacci axis rotated about +z (fibonacci.rs) for
        // narrower ones, both between (visibility.rs sos_centroid_share).
        if (centroid_share > 0.0) {
            total += sum_of_sg_term(f, space, unpack_unit_vector(sg.y), axis, lambda) * (w * centroid_share);
        }
        if (centroid_share < 1.0) {
            total += sum_of_sg_term(f, space, rotated_fibonacci_axis(q, q_count, rot), axis, lambda) * (w * (1.0 - centroid_share));
        }
    }
    return total * inv_mass / sg_mass_f32(lambda);
}

// Point q of count on the spherical Fibonacci lattice, turned about +z by the angle whose
// (cos, sin) is rot (sum_of_sg.rs rotated_axes: fibonacci.rs spherical_fibonacci, rotate_about_z).
fn rotated_fibonacci_axis(q: u32, count: u32, rot: vec2<f32>) -> vec3<f32> {
    let z = 1.0 - f32(2u * q + 1u) / f32(count);
    let r = sqrt(max((1.0 - z) * (1.0 + z), 0.0));
    let phi = 2.0 * PI * fract(f32(q) * 0.6180339887498949);
    let base = vec2<f32>(r * cos(phi), r * sin(phi));
    return vec3<f32>(rot.x * base.x - rot.y * base.y, rot.y * base.x + rot.x * base.y, z);
}

// One visibility SG (unit axis, sharpness fabric.sos_sharpness, unit weight and mass) times the
// light, scattered: Γ of their product SG times its scale (visibility.rs sum_of_sg_path).
fn sum_of_sg_term(f: FiberConstants, space: OmegaOSpace, sg_axis: vec3<f32>, axis: vec3<f32>, lambda: f32) -> vec3<f32> {
    let lambda_svf = fabric.sos_sharpness;
    let p = lambda_svf * sg_axis + lambda * axis;
    let sharpness = length(p);
    let d = sg_axis - axis;
    let loss = lambda_svf * lambda * dot(d, d) / (lambda_svf + lambda + sharpness);
    let product_axis = select(sg_axis, p / sharpness, sharpness > 0.0);
    return sg_bcsdf_gamma(f, space, product_axis, sharpness) * exp(-loss);
}

// visibility.rs sos_centroid_share: 1 while the light covers SOS_CENTROIDS_ONLY_BELOW cells'
// worth or more, 0 from a light of one cell (SOS_FIBONACCI_ONLY_ABOVE), 1 − smoothstep of the
// log ratio between.
fn sos_centroid_share(lambda: f32, q_count: u32) -> f32 {
    let ratio = 2.0 * lambda / f32(max(q_count, 1u));
    if (!(ratio > SOS_CENTROIDS_ONLY_BELOW)) {
        return 1.0;
    }
    if (ratio >= SOS_FIBONACCI_ONLY_ABOVE) {
        return 0.0;
    }
    let x = log(ratio / SOS_CENTROIDS_ONLY_BELOW) / log(SOS_FIBONACCI_ONLY_ABOVE / SOS_CENTROIDS_ONLY_BELOW);
    return 1.0 - x * x * (3.0 - 2.0 * x);
}

// z_l(lambda) of the normalized SG from the C_G table (bake::tables::CgTable::lookup).
fn cg_lookup(lambda: f32, l: u32) -> f32 {
    let points = fabric.cg_points;
    // The table's own row length (its order may exceed the transfer's: fiber lobes).
    let width = fabric.cg_order + 1u;
    let zero_limit = select(0.0, 0.28209479177387814, l == 0u);
    let inf_limit = sqrt(f32(2u * l + 1u) / (4.0 * PI));
    let lambda_min = 1e-4;
    let lambda_max = 1e5;
    if (!(lambda > lambda_min)) {
        let t = select(0.0, lambda / lambda_min, lambda > 0.0);
        return zero_limit + t * (cg_table[l] - zero_limit);
    }
    if (lambda >= lambda_max) {
        let t = lambda_max / lambda;
        return inf_limit + t * (cg_table[(points - 1u) * width + l] - inf_limit);
    }
    let x = (log(lambda) - log(lambda_min)) / (log(lambda_max) - log(lambda_min)) * f32(points - 1u);
    let k = min(u32(max(x, 0.0)), points - 2u);
    let t = clamp(x - f32(k), 0.0, 1.0);
    let a = cg_table[k * width + l];
    let b = cg_table[(k + 1u) * width + l];
    return a + t * (b - a);
}

// How much of a light takes the transfer's upper-hemisphere fit (multiple.rs upper_fit_share
// and hemisphere_light_sh): a directional light (sharpness < 0) all of it; an SG light none
// below lambda = 4, all above 40, a smoothstep in ln lambda between.
fn upper_fit_share(sharpness: f32) -> f32 {
    if (sharpness < 0.0) {
        return 1.0;
    }
    let t = clamp(log(max(sharpness, 1e-30) / 4.0) / log(10.0), 0.0, 1.0);
    return t * t * (3.0 - 2.0 * t);
}

// Sum of the sizes of the upper-hemisphere fits of orders 0..order in cg_table (after the C_G
// rows): (L + 1)(L + 2)(2L + 3) / 6 each (upper_fit.rs UpperHemisphereFit::packed_len).
fn upper_fit_offset(order: u32) -> u32 {
    var offset = fabric.cg_points * (fabric.cg_order + 1u);
    for (var l = 0u; l < order; l++) {
        offset += (l + 1u) * (l + 2u) * (2u * l + 3u) / 6u;
    }
    return offset;
}

// c <- (G + eps I)^-1 c over the upper hemisphere at `order` (upper_fit.rs
// UpperHemisphereFit::apply): block m, row-major over l = m..=order, for the coefficients
// (l, m) and again for (l, -m).
fn upper_fit_apply(order: u32, c: ptr<function, array<f32, 49>>) {
    var base = upper_fit_offset(order);
    for (var m = 0u; m <= order; m++) {
        let size = order + 1u - m;
        let kinds = select(2u, 1u, m == 0u);
        for (var kind = 0u; kind < kinds; kind++) {
            var v: array<f32, 7>;
            for (var a = 0u; a < size; a++) {
                let l = m + a;
                v[a] = (*c)[select(l * (l + 1u) - m, l * (l + 1u) + m, kind == 0u)];
            }
            for (var a = 0u; a < size; a++) {
                var sum = 0.0;
                for (var b = 0u; b < size; b++) {
                    sum += cg_table[base + a * size + b] * v[b];
                }
                let l = m + a;
                (*c)[select(l * (l + 1u) - m, l * (l + 1u) + m, kind == 0u)] = sum;
            }
        }
        base += size * size;
    }
}

// A light's SH for unit colour as the transfer takes it (multiple.rs hemisphere_light_sh over
// the light's colour): directional (sharpness < 0) Y_j(dir), nothing from below the horizon; SG
// sqrt(4 pi / (2l + 1)) z_l Y_j(dir); blended by upper_fit_share toward the upper-hemisphere
// fit scaled by the light's share above the horizon (1, or sg_upper_fraction_f32); below
// UPPER_FIT_MIN_ORDER (upper_fit.rs, written into the prelude) the plain SH.
fn hemisphere_light_sh(order: u32, dir: vec3<f32>, sharpness: f32, c: ptr<function, array<f32, 49>>) {
    sh_eval_f32(order, dir, c);
    let fits = order >= UPPER_FIT_MIN_ORDER;
    if (fits && sharpness < 0.0 && !(dir.z > 0.0)) {
        for (var j = 0u; j < 49u; j++) {
            (*c)[j] = 0.0;
        }
        return;
    }
    if (sharpness >= 0.0) {
        for (var l = 0u; l <= order; l++) {
            let scale = cg_lookup(sharpness, l) * sqrt(4.0 * PI / f32(2u * l + 1u));
            for (var j = l * l; j < (l + 1u) * (l + 1u); j++) {
                (*c)[j] *= scale;
            }
        }
    }
    let share = upper_fit_share(sharpness);
    if (fits && share > 0.0) {
        var upper = 1.0;
        if (sharpness >= 0.0) {
            upper = sg_upper_fraction_f32(dir.z, sharpness);
        }
        var fitted = *c;
        upper_fit_apply(order, &fitted);
        for (var j = 0u; j < (order + 1u) * (order + 1u); j++) {
            (*c)[j] += share * (upper * fitted[j] - (*c)[j]);
        }
    }
}

// Adds a light's SH coefficients as the transfer takes them (hemisphere_light_sh) times
// `weight` to `c`.
fn hemisphere_light_sh_accumulate(order: u32, dir: vec3<f32>, sharpness: f32, weight: vec3<f32>, c: ptr<function, array<vec3<f32>, 49>>) {
    var y: array<f32, 49>;
    hemisphere_light_sh(order, dir, sharpness, &y);
    for (var j = 0u; j < (order + 1u) * (order + 1u); j++) {
        (*c)[j] += weight * y[j];
    }
}

// Adds `light`'s SH coefficients from direction `dir` (flat-fabric frame) times `weight` to `c`
// (hemisphere_light_sh_accumulate for its kind).
fn light_sh_add(light: LightGpu, dir: vec3<f32>, weight: vec3<f32>, c: ptr<function, array<vec3<f32>, 49>>) {
    let sharpness = select(-1.0, light.sharpness, light.kind == LIGHT_SG);
    hemisphere_light_sh_accumulate(fabric.sh_order, dir, sharpness, weight, c);
}

// Adds weight * (A_cell c_in), channel by channel, to c_t, for the cell in `slot`
// (multiple.rs add_transferred).
fn add_transferred(slot: u32, weight: f32, n: u32, c_in: ptr<function, array<vec3<f32>, 49>>, c_t: ptr<function, array<vec3<f32>, 49>>) {
    for (var j1 = 0u; j1 < n; j1++) {
        var sum = vec3<f32>(0.0);
        for (var j0 = 0u; j0 < n; j0++) {
            let a = vec3<f32>(iirtf_entry(slot, 0u, j0, j1), iirtf_entry(slot, 1u, j0, j1), iirtf_entry(slot, 2u, j0, j1));
            sum += a * (*c_in)[j0];
        }
        (*c_t)[j1] += weight * sum;
    }
}

// c_T = A c_in interpolated between the cells around the shaded point p (exemplar cm;
// CellGrid::interpolation), or the segment's own cell where all eight are empty, added to
// `coeffs` (multiple.rs multiple_scattering, its first half).
fn transferred_at(e: u32, segment: u32, p: vec3<f32>, c_in: ptr<function, array<vec3<f32>, 49>>, coeffs: ptr<function, array<vec3<f32>, 49>>) {
    let around = transfer_cells(e, segment, p);
    for (var k = 0u; k < 8u; k++) {
        if (around.weights[k] > 0.0) {
            add_transferred(around.slots[k], around.weights[k], fabric.sh_count, c_in, coeffs);
        }
    }
}

// No lobes (lobe_base): the cell keeps none.
const NO_LOBES: u32 = 0xffffffffu;

// The first vec4 of the lobes of the cell in `slot` (fabric_data.wgsl: after the lobe table,
// its lobe slot's), or NO_LOBES for a cell without a lobe slot: a segment cell (its slot lies
// past the table's lattice slots) or one that kept no lobes at the bake's colours, and every
// cell of a bake without lobes (lobe_table_vec4s 0).
fn lobe_base(slot: u32) -> u32 {
    if (slot >= 4u * fabric.lobe_table_vec4s) {
        return NO_LOBES;
    }
    let lobe_slot = bitcast<u32>(lobes[slot / 4u][slot % 4u]);
    let base = fabric.lobe_table_vec4s + (lobe_slot - 1u) * LOBE_PACKED_VEC4S;
    if (lobe_slot == 0u || base + LOBE_PACKED_VEC4S > arrayLength(&lobes)) {
        return NO_LOBES;
    }
    return base;
}

// Whether the lobes from vec4 `base` (lobe_base) carry light: a nonzero strength (each
// strength[0] sums non-negative shares; the lobes a recolouring folded into the cell's matrix
// are all zeros, lobes that carry no light have no strength either).
fn lobes_carry_light(base: u32) -> bool {
    if (base == NO_LOBES) {
        return false;
    }
    return any(lobes[base].xyz != vec3<f32>(0.0)) || any(lobes[base + LOBE_SH_COUNT].xyz != vec3<f32>(0.0));
}

// Whether the cell in `slot` keeps fiber lobes that carry light.
fn slot_keeps_lobes(slot: u32) -> bool {
    return lobes_carry_light(lobe_base(slot));
}

// The slot (plus one) of `segment`'s own segment cell, 0 where the bake has none for it or a
// live recolouring took its slot away (multiple.rs segment_transfer).
fn segment_cell_slot(segment: u32) -> u32 {
    let s = segments[segment];
    if (s.segment_cell == NO_SEGMENT_CELL) {
        return 0u;
    }
    return cell_slots[s.segment_cell];
}

// The cells whose transfer is shaded at point p of `segment` (multiple.rs
// segment_transfer, multiple_scattering): its own segment cell alone (weight 1) where the bake
// has one for it (all of its light, or where its lattice cell keeps fiber lobes its reflected
// light, beside the lattice's forward lobes: fiber_lobes_at); else lattice_cells_around.
fn transfer_cells(e: u32, segment: u32, p: vec3<f32>) -> CellWeights {
    let own_slot = segment_cell_slot(segment);
    if (own_slot != 0u) {
        var alone: CellWeights;
        alone.slots[0] = own_slot - 1u;
        alone.weights[0] = 1.0;
        return alone;
    }
    return lattice_cells_around(e, segment, p);
}

// The point the transfer is interpolated at (Baked::transfer_point): p's projection on the
// segment's axis, clamped to its ends, in the copy of a periodic exemplar that holds p (cells
// hold the segments whose midpoints they contain).
fn transfer_point(e: u32, segment: u32, p: vec3<f32>) -> vec3<f32> {
    let s = segments[segment];
    let ex = exemplars[e];
    var offset = p - s.midpoint;
    if (ex.periodic != 0u) {
        offset = vec3<f32>(offset.xy - ex.period * round(offset.xy / ex.period), offset.z);
    }
    let along = clamp(dot(offset, s.direction), -s.half_length, s.half_length);
    return p - offset + along * s.direction;
}

// The lattice cells interpolated around p's point on the segment's axis (transfer_point,
// cell_interpolation), or, where all eight are empty, `segment`'s lattice cell alone if it
// has a transfer; every weight 0 if none.
fn lattice_cells_around(e: u32, segment: u32, p: vec3<f32>) -> CellWeights {
    let s = segments[segment];
    var around = cell_interpolation(e, transfer_point(e, segment, p));
    var found = false;
    for (var k = 0u; k < 8u; k++) {
        found = found || around.weights[k] > 0.0;
    }
    let own = cell_slots[s.cell];
    if (!found && own != 0u) {
        around.slots[0] = own - 1u;
        around.weights[0] = 1.0;
    }
    return around;
}

// Multiple scattering from the transferred light c_T at the shaded point (multiple.rs
// multiple_scattering, its second half): per channel, C_S[theta_o] . (R_wo c_T).
fn multiple_from_transferred(segment: u32, wo: vec3<f32>, coeffs: ptr<function, array<vec3<f32>, 49>>) -> vec3<f32> {
    let s = segments[segment];
    let m = materials[s.material];
    if (m.model != MATERIAL_FIBER) {
        return vec3<f32>(0.0);
    }
    let order = fabric.sh_order;
    let n = fabric.sh_count;
    let space = omega_o_space(normalize(s.direction), wo);
    let rotation = transpose(mat3x3<f32>(space.t, space.b, space.c));
    // C_S row interpolation, linear in theta_o, clamped.
    let rows = fabric.cs_theta_count;
    let x = clamp((space.theta_o + HALF_PI) / PI * f32(rows - 1u), 0.0, f32(rows - 1u));
    let k = min(u32(x), rows - 2u);
    let ft = x - f32(k);
    // One rotation into omega_o-space for all three channels.
    sh_rotate_rgb_f32(order, rotation, coeffs);
    var out = vec3<f32>(0.0);
    for (var j = 0u; j < n; j++) {
        let row0 = ((s.material * rows + k) * n + j) * 3u;
        let row1 = ((s.material * rows + k + 1u) * n + j) * 3u;
        let a = vec3<f32>(cs_table[row0], cs_table[row0 + 1u], cs_table[row0 + 2u]);
        let b = vec3<f32>(cs_table[row1], cs_table[row1 + 1u], cs_table[row1 + 2u]);
        out += (*coeffs)[j] * (a + ft * (b - a));
    }
    return out;
}

// Multiple scattering (multiple.rs multiple_scattering): per channel,
// C_S[theta_o] . (R_wo c_T), c_T = A c_in interpolated between the cells around the shaded
// point p (exemplar cm; CellGrid::interpolation), or the segment's own cell where all eight
// are empty.
fn shade_multiple(e: u32, segment: u32, p: vec3<f32>, wo: vec3<f32>, c_in: ptr<function, array<vec3<f32>, 49>>) -> vec3<f32> {
    var coeffs: array<vec3<f32>, 49>;
    for (var j = 0u; j < fabric.sh_count; j++) {
        coeffs[j] = vec3<f32>(0.0);
    }
    transferred_at(e, segment, p, c_in, &coeffs);
    return multiple_from_transferred(segment, wo, &coeffs);
}


// ---- Fiber lobes (BakeSettings::fiber_lobes): multiple.rs lobe_scattering, FiberLobe;
// gamma.rs LobeAngles, lobe_quadrature. A cell that keeps lobes holds its light as two of
// them instead of its matrix (the forward chains, then the light reflected at least once),
// each a strength over light directions (SH at LOBE_SH_ORDER) and a shape in the fiber frame
// (`lobes` in shared/fabric_data.wgsl, CellTransfer::pack_lobes' layout). Per light, each
// lobe's strength for the light times its unit shape scattered toward wo by the shaded fiber.

// Where a lobe's light arrives from, per unit strength (gamma.rs LobeAngles): about an axis xi
// at fiber angles (theta', phi'), L dwi = p(theta_i - theta') v(phi_i - phi') dtheta_i dphi_i,
// p the Fourier series [c_1, s_1, c_2, s_2, ...] of the longitudinal offset and v the series
// [a_1, b_1, a_2, b_2, ...] of the azimuthal one (turning in the positive sense about t).
struct LobeAngles {
    fourier: array<f32, 2u * LOBE_FOURIER_TERMS>,
    azimuth: array<f32, 2u * LOBE_AZIMUTH_TERMS>,
}

// I_k(kappa) / I_0(kappa) for k = 1..LOBE_AZIMUTH_TERMS (special.rs bessel_i_ratios): the
// continued fraction r_k = 1 / (2k / kappa + r_(k+1)) run down from BESSEL_RATIO_DEPTH terms
// above the last and multiplied up, or exp(-k^2 / 2 kappa) above BESSEL_RATIO_GAUSSIAN_ABOVE;
// zero for kappa <= 0.
fn bessel_i_ratios(kappa: f32) -> array<f32, LOBE_AZIMUTH_TERMS> {
    var out: array<f32, LOBE_AZIMUTH_TERMS>;
    if (!(kappa > 0.0)) {
        return out;
    }
    if (kappa > BESSEL_RATIO_GAUSSIAN_ABOVE) {
        for (var k = 0u; k < LOBE_AZIMUTH_TERMS; k++) {
            let order = f32(k + 1u);
            out[k] = exp(-order * order / (2.0 * kappa));
        }
        return out;
    }
    var r = 0.0;
    for (var k = LOBE_AZIMUTH_TERMS + BESSEL_RATIO_DEPTH; k > LOBE_AZIMUTH_TERMS; k--) {
        r = 1.0 / (2.0 * f32(k) / kappa + r);
    }
    for (var k = LOBE_AZIMUTH_TERMS; k > 0u; k--) {
        r = 1.0 / (2.0 * f32(k) / kappa + r);
        out[k - 1u] = r;
    }
    var product = 1.0;
    for (var k = 0u; k < LOBE_AZIMUTH_TERMS; k++) {
        product *= out[k];
        out[k] = product;
    }
    return out;
}

// The TT lobe's von Mises about pi convolved with the lobe's azimuthal series at
// Phi = phi_o - phi' (gamma.rs lobe_tt_azimuth): (1 + 2 sum_k (-1)^k rho_k (a_k cos k Phi +
// b_k sin k Phi)) / 2 pi, clamped at zero, with rho_k = I_k(kappa_TT) / I_0(kappa_TT).
fn lobe_tt_azimuth(angles: ptr<function, LobeAngles>, tt_ratios: array<f32, LOBE_AZIMUTH_TERMS>, cos_phi: f32, sin_phi: f32) -> f32 {
    var ck = cos_phi;
    var sk = sin_phi;
    var sign = -1.0;
    var v = 1.0;
    for (var k = 0u; k < LOBE_AZIMUTH_TERMS; k++) {
        v += 2.0 * sign * tt_ratios[k] * ((*angles).azimuth[2u * k] * ck + (*angles).azimuth[2u * k + 1u] * sk);
        let next = ck * cos_phi - sk * sin_phi;
        sk = sk * cos_phi + ck * sin_phi;
        ck = next;
        sign = -sign;
    }
    return max(v / (2.0 * PI), 0.0);
}

// p(dtheta) = (1 + 2 sum_k c_k cos k dtheta + s_k sin k dtheta) / 2 pi, clamped at zero
// (gamma.rs LobeAngles::longitudinal): cos k dtheta and sin k dtheta by the same rotation
// recurrence.
fn lobe_longitudinal(angles: ptr<function, LobeAngles>, delta_theta: f32) -> f32 {
    let s1 = sin(delta_theta);
    let c1 = cos(delta_theta);
    var sk = s1;
    var ck = c1;
    var v = 1.0;
    for (var k = 0u; k < LOBE_FOURIER_TERMS; k++) {
        v += 2.0 * ((*angles).fourier[2u * k] * ck + (*angles).fourier[2u * k + 1u] * sk);
        let next = ck * c1 - sk * s1;
        sk = sk * c1 + ck * s1;
        ck = next;
    }
    return max(v / (2.0 * PI), 0.0);
}

// int L(wi) S(wi, wo) cos(theta_i) dwi for the unit lobe `angles` about unit xi, per RGB channel
// (gamma.rs lobe_quadrature). The phi_i integrals are exact for the series: S_R's azimuth is
// uniform (1 / 2 pi against v); S_TT's von Mises about phi = pi convolved with v is
// lobe_tt_azimuth at phi_o - phi' (in omega_o-space, -phi'), with tt_ratios the fiber's
// bessel_i_ratios(kappa_TT) (FiberConstants::tt_ratios, which the caller computes once). The
// theta_i integral per lobe X is the composite LOBE_NODES-point Gauss-Legendre rule over
// the lobe's Gaussian exp(-lambda_X (theta_i + theta_o)^2) out to LOBE_WINDOW deviations either
// side, clipped to [-pi/2, pi/2], in equal panels no wider than LOBE_PANEL_WIDTH, with p,
// cos(theta_i), Gn and Fresnel exact at each node. The
// interval is held in the offset theta_i + theta_o (the twin's theta_i minus its centre), which
// f32 keeps exact where the window is not clipped.
fn lobe_quadrature(f: FiberConstants, tt_ratios: array<f32, LOBE_AZIMUTH_TERMS>, space: OmegaOSpace, xi: vec3<f32>, angles: ptr<function, LobeAngles>) -> vec3<f32> {
    let axis = sg_axis_in_omega_o_space(space, xi);
    var cos_phi = 1.0;
    var sin_phi = 0.0;
    if (axis.h > 0.0) {
        cos_phi = dot(space.b, xi) / axis.h;
        sin_phi = -dot(space.c, xi) / axis.h;
    }
    let tt_azimuth = lobe_tt_azimuth(angles, tt_ratios, cos_phi, sin_phi);
    var nodes = LOBE_LEGENDRE_NODES;
    var weights = LOBE_LEGENDRE_WEIGHTS;
    var out = vec3<f32>(0.0);
    for (var lobe = LOBE_R; lobe <= LOBE_TT; lobe++) {
        let lambda_lobe = select(f.lambda_r, f.lambda_tt, lobe == LOBE_TT);
        let reach = LOBE_WINDOW * sqrt(0.5 / lambda_lobe);
        let lo = max(-reach, -HALF_PI + space.theta_o);
        let hi = min(reach, HALF_PI + space.theta_o);
        if (hi <= lo) {
            continue;
        }
        let panels = clamp(ceil((hi - lo) / LOBE_PANEL_WIDTH), 1.0, f32(LOBE_MAX_PANELS));
        let half = 0.5 * (hi - lo) / panels;
        let norm = sqrt(lambda_lobe / PI);
        var sum = 0.0;
        var fresnel_sum = vec3<f32>(0.0);
        for (var panel = 0u; panel < u32(panels); panel++) {
            let mid = lo + (2.0 * f32(panel) + 1.0) * half;
            for (var k = 0u; k < LOBE_NODES; k++) {
                let offset = mid + half * nodes[k];
                let theta = offset - space.theta_o;
                let c = cos(theta);
                let term = c * norm * exp(-lambda_lobe * offset * offset) * lobe_longitudinal(angles, theta - axis.theta)
                    / gn_eval(f.material, lobe, -theta) * (weights[k] * half);
                sum += term;
                fresnel_sum += fresnel(f, c) * term;
            }
        }
        if (lobe == LOBE_R) {
            out += fresnel_sum / (2.0 * PI);
        } else {
            out += (vec3<f32>(sum) - fresnel_sum) * f.c_tt * tt_azimuth;
        }
    }
    return out;
}

// The fiber lobes around a shaded point: the cells and weights the transfer is interpolated
// with (transfer_cells, multiple.rs lobe_scattering's cells), the cells without lobes given
// weight 0, and both lobes' interpolated strength[0] per channel and the shapes' node totals
// per channel (elevation nodes, then longitudinal ones; multiple.rs FiberLobe: weighted sums of
// strength[0] and of the shapes). The strengths over light directions and the sums per node stay
// in the buffer and are read per light (fiber_lobe_strengths, lobe_node_mean), so that they
// need not live in every invocation's registers.
struct FiberLobesAt {
    // The cells around the point; fiber_lobes_at turns their slots into their lobes' lobe_base.
    around: CellWeights,
    // Whether the reflected lobe is left out: the segment's own transfer holds its reflected
    // light (multiple.rs LobesTaken::ForwardOnly).
    forward_only: bool,
    // The interpolated strength[0] per channel: forward [0] and reflected [1].
    total: array<vec3<f32>, 2>,
    // Per lobe (forward, then reflected) and colour channel (its shape, lobe_shape_index) the
    // shape's node totals: LOBE_AZIMUTH_BINS elevation nodes', then LOBE_LONGITUDINAL_BINS
    // longitudinal nodes'.
    shapes: array<f32, 6u * LOBE_GATHERED>,
}

const LOBE_GATHERED: u32 = LOBE_LONGITUDINAL_AT - LOBE_AZIMUTH_TOTALS;

// Float i of the shapes of the lobes from vec4 `base` (lobe_base: the forward shape's floats,
// then the reflected shape's, each a LOBE_CHANNEL_SHAPE_LEN shape per colour channel, as
// CellTransfer::pack_lobes lays them out after the strengths).
fn lobe_shape_float(base: u32, i: u32) -> f32 {
    return lobes[base + 2u * LOBE_SH_COUNT + i / 4u][i % 4u];
}

// Which of the six shapes of a cell's lobes is colour channel `channel` of lobe `lobe` (0
// forward, 1 reflected): red, green, blue of the forward lobe, then of the reflected one.
fn lobe_shape_index(lobe: u32, channel: u32) -> u32 {
    return lobe * 3u + channel;
}

// The two of `bins` evenly spaced nodes on [0, 1] around x, as (lower node, its weight, the
// upper one's weight) (iirtf.rs node_hats): elevation_hats(z) with LOBE_AZIMUTH_BINS,
// longitudinal_hats(dir . t) over (1 + dir . t) / 2 with LOBE_LONGITUDINAL_BINS.
fn node_hats(x: f32, bins: u32) -> vec3<f32> {
    let at = clamp(x, 0.0, 1.0) * f32(bins - 1u);
    let lower = min(u32(floor(at)), bins - 2u);
    let upper_weight = at - f32(lower);
    return vec3<f32>(f32(lower), 1.0 - upper_weight, upper_weight);
}

// Fills `at` for the shaded point p (exemplar cm) of `segment` (multiple.rs lobe_scattering,
// its first half); false when no cell around p holds lobes (the term is then zero).
fn fiber_lobes_at(e: u32, segment: u32, p: vec3<f32>, at: ptr<function, FiberLobesAt>) -> bool {
    (*at).forward_only = false;
    if (segment_cell_slot(segment) != 0u) {
        // A segment with its own transfer: where its lattice cell keeps lobes, that transfer
        // holds the reflected light and the forward chains come from the lattice's forward
        // lobes, their weights renormalized over the cells that keep lobes; else no lobes.
        let lattice_slot = cell_slots[segments[segment].cell];
        if (!(lattice_slot != 0u && slot_keeps_lobes(lattice_slot - 1u))) {
            return false;
        }
        (*at).forward_only = true;
    }
    (*at).around = lattice_cells_around(e, segment, p);
    (*at).total = array<vec3<f32>, 2>(vec3<f32>(0.0), vec3<f32>(0.0));
    for (var i = 0u; i < 6u * LOBE_GATHERED; i++) {
        (*at).shapes[i] = 0.0;
    }
    // From here on `around.slots` holds each cell's lobe_base, read by every later step.
    var lobed = 0.0;
    for (var k = 0u; k < 8u; k++) {
        let w = (*at).around.weights[k];
        let base = lobe_base((*at).around.slots[k]);
        (*at).around.slots[k] = base;
        if (w > 0.0 && lobes_carry_light(base)) {
            lobed += w;
        } else {
            (*at).around.weights[k] = 0.0;
        }
    }
    if ((*at).forward_only && lobed > 0.0) {
        for (var k = 0u; k < 8u; k++) {
            (*at).around.weights[k] /= lobed;
        }
    }
    // The reflected lobe's shape is not gathered where fiber_lobes_light leaves it out.
    let lobe_count = select(2u, 1u, (*at).forward_only);
    var any = false;
    for (var k = 0u; k < 8u; k++) {
        let w = (*at).around.weights[k];
        if (!(w > 0.0)) {
            continue;
        }
        let base = (*at).around.slots[k];
        any = true;
        (*at).total[0] += w * lobes[base].xyz;
        (*at).total[1] += w * lobes[base + LOBE_SH_COUNT].xyz;
        for (var shape = 0u; shape < 3u * lobe_count; shape++) {
            for (var i = 0u; i < LOBE_GATHERED; i++) {
                (*at).shapes[shape * LOBE_GATHERED + i] += w * lobe_shape_float((*at).around.slots[k], shape * LOBE_CHANNEL_SHAPE_LEN + LOBE_AZIMUTH_TOTALS + i);
            }
        }
    }
    return any;
}

// A light's SH at LOBE_SH_ORDER for unit colour as the lobes' strengths take it (multiple.rs
// hemisphere_light_sh at LOBE_SH_ORDER over the light's colour; the C_G table's order, which
// the packing checks is at least LOBE_SH_ORDER for a bake with lobes, and its fits cover it).
fn lobe_light_sh(dir: vec3<f32>, sharpness: f32, c: ptr<function, array<f32, 49>>) {
    hemisphere_light_sh(LOBE_SH_ORDER, dir, sharpness, c);
}

// Both lobes' strength for the light of SH `c` (FiberLobe::strength_for of the interpolated
// lobes: sum_j strength_j c_j, the cells' weighted sum taken per cell), per channel, signed:
// [0] forward, [1] reflected.
fn fiber_lobe_strengths(at: ptr<function, FiberLobesAt>, c: ptr<function, array<f32, 49>>) -> array<vec3<f32>, 2> {
    var out = array<vec3<f32>, 2>(vec3<f32>(0.0), vec3<f32>(0.0));
    for (var k = 0u; k < 8u; k++) {
        let w = (*at).around.weights[k];
        if (!(w > 0.0)) {
            continue;
        }
        let base = (*at).around.slots[k];
        var forward = vec3<f32>(0.0);
        var reflected = vec3<f32>(0.0);
        for (var j = 0u; j < LOBE_SH_COUNT; j++) {
            forward += lobes[base + j].xyz * (*c)[j];
            reflected += lobes[base + LOBE_SH_COUNT + j].xyz * (*c)[j];
        }
        out[0] += w * forward;
        out[1] += w * reflected;
    }
    return out;
}

// Where colour channel `channel` of lobe `lobe` (0 forward, 1 reflected) of `at` brings the
// light from direction `dir`
// (sharpness < 0: directional, else an SG of that sharpness) at a fiber of unit tangent t
// (multiple.rs FiberLobe::angles): writes the axis (dir) and the angles' series and returns
// true, or false for a lobe without light in that channel. The shape's means are taken per elevation node
// (azimuth) and per node of dir . t (longitudinal), lobe_node_mean, both series smoothed by
// Jackson's factors; the azimuth's odd terms
// turn with toward_up(t, dir), and all of its terms fade out within AZIMUTH_FADE_ACROSS of a
// light along t (1 - (dir.t)^2 taken as |dir x t|^2, without its f32 cancellation near t). An
// SG light widens both: the longitudinal terms are damped by exp(-k^2 / 2 lambda), the
// azimuthal ones by I_k(kappa_l) / I_0(kappa_l) with kappa_l = lambda |dir x t|^2.
fn fiber_lobe_angles(at: ptr<function, FiberLobesAt>, lobe: u32, channel: u32, dir: vec3<f32>, sharpness: f32, t: vec3<f32>, axis: ptr<function, vec3<f32>>, angles: ptr<function, LobeAngles>) -> bool {
    let total = (*at).total[lobe][channel];
    if (!(total > 0.0)) {
        return false;
    }
    let shape = lobe_shape_index(lobe, channel);
    let across_vec = cross(dir, t);
    let across = dot(across_vec, across_vec);
    let fade = min(across / AZIMUTH_FADE_ACROSS, 1.0);
    let odd = toward_up(t, dir);
    var light_ratios: array<f32, LOBE_AZIMUTH_TERMS>;
    for (var k = 0u; k < LOBE_AZIMUTH_TERMS; k++) {
        light_ratios[k] = 1.0;
    }
    if (sharpness >= 0.0) {
        light_ratios = bessel_i_ratios(sharpness * across);
    }
    let elevation = node_hats(fiber_elevation(t, dir), LOBE_AZIMUTH_BINS);
    for (var k = 0u; k < LOBE_AZIMUTH_TERMS; k++) {
        let scale = LOBE_AZIMUTH_JACKSON[k] * fade * light_ratios[k];
        (*angles).azimuth[2u * k] = scale * lobe_node_mean(at, shape, elevation, 0u, 0u, 2u * LOBE_AZIMUTH_TERMS, 2u * k);
        (*angles).azimuth[2u * k + 1u] = scale * odd * lobe_node_mean(at, shape, elevation, 0u, 0u, 2u * LOBE_AZIMUTH_TERMS, 2u * k + 1u);
    }
    // The means E cos k dtheta, E sin k dtheta, smoothed by Jackson's factors (LobeAngles::from_means):
    // the cut series of a sharp offset would ring below zero; the smoothed one is a density.
    let longitudinal = node_hats(0.5 * (dot(dir, t) + 1.0), LOBE_LONGITUDINAL_BINS);
    for (var i = 0u; i < 2u * LOBE_FOURIER_TERMS; i++) {
        (*angles).fourier[i] = LOBE_JACKSON[i / 2u] * lobe_node_mean(at, shape, longitudinal, LOBE_AZIMUTH_BINS, LOBE_LONGITUDINAL_AT, 2u * LOBE_FOURIER_TERMS, i);
    }
    if (sharpness >= 0.0) {
        for (var k = 0u; k < LOBE_FOURIER_TERMS; k++) {
            let order = f32(k + 1u);
            let damping = exp(-order * order / (2.0 * max(sharpness, 1e-30)));
            (*angles).fourier[2u * k] *= damping;
            (*angles).fourier[2u * k + 1u] *= damping;
        }
    }
    *axis = dir;
    return true;
}

// Mean i of shape `shape` (lobe_shape_index) of `at` over the two nodes `hats` (node_hats) of
// one kind (multiple.rs FiberLobe::node_means): each node's sum over the cells (read from the
// buffer, `terms` per node from float `sums_at` of the shape) over its total (gathered, from
// `totals_at`), weighted by its hat; a node without weight counts as uniform (mean 0).
fn lobe_node_mean(at: ptr<function, FiberLobesAt>, shape: u32, hats: vec3<f32>, totals_at: u32, sums_at: u32, terms: u32, i: u32) -> f32 {
    var mean = 0.0;
    for (var side = 0u; side < 2u; side++) {
        let node = u32(hats.x) + side;
        let hat = select(hats.y, hats.z, side == 1u);
        let total = (*at).shapes[shape * LOBE_GATHERED + totals_at + node];
        if (!(total > 0.0) || !(hat > 0.0)) {
            continue;
        }
        let float_at = shape * LOBE_CHANNEL_SHAPE_LEN + sums_at + node * terms + i;
        var sum = 0.0;
        for (var k = 0u; k < 8u; k++) {
            let w = (*at).around.weights[k];
            if (w > 0.0) {
                sum += w * lobe_shape_float((*at).around.slots[k], float_at);
            }
        }
        mean += hat * sum / total;
    }
    return mean;
}

// The light's elevation about the fiber (iirtf.rs fiber_elevation): the cosine, in the plane
// normal to t, between dir and the fabric's up, (dir.z - (dir.t) t.z) / (|dir x t| |t.xy|)
// clamped to [0, 1]; dir's own z where either projection vanishes.
fn fiber_elevation(t: vec3<f32>, dir: vec3<f32>) -> f32 {
    let scale = length(cross(dir, t)) * length(t.xy);
    if (scale < 1e-6) {
        return clamp(dir.z, 0.0, 1.0);
    }
    return clamp((dir.z - dot(dir, t) * t.z) / scale, 0.0, 1.0);
}

// Which way about t the fabric's up lies from dir (iirtf.rs toward_up): t . (dir x z) over
// TOWARD_UP_WIDTH, clamped to [-1, 1].
fn toward_up(t: vec3<f32>, dir: vec3<f32>) -> f32 {
    return clamp(dot(t, cross(dir, vec3<f32>(0.0, 0.0, 1.0))) / TOWARD_UP_WIDTH, -1.0, 1.0);
}

// The fiber lobes' radiance toward wo for one light of unit colour from `dir` (flat-fabric
// frame; sharpness < 0: directional, else an SG of that sharpness), without V_glo and the
// light's colour, which the caller multiplies in (multiple.rs lobe_scattering, its per-light
// sum): per lobe and colour channel, s lobe_quadrature(...) with s the lobe's strength for the
// light, signed (FiberLobe::strength_for: only the pixel's mean is clamped), and the channel's
// own shape. `at` from fiber_lobes_at.
fn fiber_lobes_light(segment: u32, wo: vec3<f32>, dir: vec3<f32>, sharpness: f32, at: ptr<function, FiberLobesAt>) -> vec3<f32> {
    var c: array<f32, 49>;
    lobe_light_sh(dir, sharpness, &c);
    let strengths = fiber_lobe_strengths(at, &c);
    let s = segments[segment];
    let t = normalize(s.direction);
    let f = fiber_constants(s.material);
    let space = omega_o_space(t, wo);
    // The TT lobe's azimuthal Fourier coefficients, once for both lobes (FiberConstants::tt_ratios).
    let tt_ratios = bessel_i_ratios(f.kappa);
    // An SG light's shapes follow its part above the horizon (FiberLobe::angles).
    var shape_dir = dir;
    var shape_sharpness = sharpness;
    if (sharpness > 0.0) {
        let above = sg_above_horizon_f32(dir, sharpness);
        shape_dir = above.xyz;
        shape_sharpness = above.w;
    }
    var out = vec3<f32>(0.0);
    let lobe_count = select(2u, 1u, (*at).forward_only);
    for (var lobe = 0u; lobe < lobe_count; lobe++) {
        let strength = strengths[lobe];
        if (all(strength == vec3<f32>(0.0))) {
            continue;
        }
        for (var channel = 0u; channel < 3u; channel++) {
            if (strength[channel] == 0.0) {
                continue;
            }
            var axis: vec3<f32>;
            var angles: LobeAngles;
            if (fiber_lobe_angles(at, lobe, channel, shape_dir, shape_sharpness, t, &axis, &angles)) {
                out[channel] += strength[channel] * lobe_quadrature(f, tt_ratios, space, axis, &angles)[channel];
            }
        }
    }
    return out;
}

// The fiber lobes' radiance of `light` (from direction `dir`, flat-fabric frame) at the shaded
// point p of `segment` toward wo, with its colour and without V_glo (multiple.rs
// lobe_scattering for one light of V_glo = 1): fiber_lobes_at and fiber_lobes_light in one.
// The shading pass calls the two halves itself, to gather the cells once per pixel.
fn shade_fiber_lobes(e: u32, segment: u32, p: vec3<f32>, wo: vec3<f32>, light: LightGpu, dir: vec3<f32>) -> vec3<f32> {
    var at: FiberLobesAt;
    if (!fiber_lobes_at(e, segment, p, &at)) {
        return vec3<f32>(0.0);
    }
    let sharpness = select(-1.0, light.sharpness, light.kind == LIGHT_SG);
    return light.color * fiber_lobes_light(segment, wo, dir, sharpness, &at);
}
