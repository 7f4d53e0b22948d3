//! What a paint file was precomputed from: fingerprints of the scene's camera, its lights and
//! its cloth, so that `twill paint verify` and `commit` refuse a scene the paths were not
//! traced in, naming what differs.
//!
//! How it works: each key is the BLAKE3 hash of a TOML rendering of what the colour-free paths
//! depend on. The cloth key covers the fabric, the swatch (size and ground), the yarn materials
//! as resolved from the preset, `[materials]` and the colourway, with their paintable colour
//! (a fiber's C_TT, a Lambertian yarn's albedo) left out, which yarn carries which of them (the
//! colour orders as palette indices, not names). (The path depth and the image size are the
//! paint file's own settings.) So a scene recoloured
//! after the precompute keeps its keys (unpainted cells keep the paint file's colours), and
//! one whose C_R, lobe widths, weave, camera or lights changed does not.

use serde::Serialize;

use crate::Rgb;
use crate::bcsdf::MaterialDesc;
use crate::scene::SceneFile;

/// Fingerprints of what a paint file's paths were traced in ([module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SceneKeys {
    pub camera: [u8; 32],
    pub lights: [u8; 32],
    pub cloth: [u8; 32],
}

#[derive(Serialize)]
struct Lights<'a> {
    lights: &'a [crate::scene::LightSection],
}

#[derive(Serialize)]
struct Cloth<'a> {
    fabric: &'a crate::scene::FabricSection,
    swatch: &'a crate::scene::SwatchSection,
    /// The yarn materials without their paintable colour, in slot (or palette) order.
    materials: Vec<MaterialDesc>,
    /// Palette index per thread of each colour order (empty without a colourway).
    warp_order: Vec<u32>,
    weft_order: Vec<u32>,
}

fn hash(value: &impl Serialize) -> Result<[u8; 32], String> {
    let text = toml::to_string(value).map_err(|e| format!("cannot fingerprint the scene: {e}"))?;
    Ok(*blake3::hash(text.as_bytes()).as_bytes())
}

impl SceneKeys {
    /// The keys of `file`.
    ///
    /// # Errors
    /// When its `[materials]` do not resolve (the message `build` would give).
    pub fn of(file: &SceneFile) -> Result<Self, String> {
        let colourless = |m: MaterialDesc| match m {
            MaterialDesc::Fiber(mut f) => {
                f.c_tt = Rgb::ZERO;
                MaterialDesc::Fiber(f)
            }
            MaterialDesc::Lambert { .. } => MaterialDesc::Lambert { albedo: Rgb::ZERO },
        };
        let materials =
            file.material_descs().map_err(|e| e.to_string())?.into_iter().map(colourless).collect();
        let colourway = file.colourway()?;
        let order = |pick: fn(&crate::scene::Colourway) -> &[u32]| {
            colourway.as_ref().map_or_else(Vec::new, |c| pick(c).to_vec())
        };
        let cloth = Cloth {
            fabric: &file.fabric,
            swatch: &file.swatch,
            materials,
            warp_order: order(|c| c.warp.threads()),
            weft_order: order(|c| c.weft.threads()),
        };
        Ok(Self {
            camera: hash(&file.camera)?,
            lights: hash(&Lights { lights: &file.lights })?,
            cloth: hash(&cloth)?,
        })
    }

    /// What differs between `self` (a paint file's) and `now` (a scene's), in words; empty
    /// when nothing does.
    #[must_use]
    pub fn differences(&self, now: &Self) -> Vec<&'static str> {
        let mut out = Vec::new();
        if self.camera != now.camera {
            out.push("the camera");
        }
        if self.lights != now.lights {
            out.push("the lights");
        }
        if self.cloth != now.cloth {
            out.push("the cloth (fabric, swatch, or a yarn material other than its paintable colour)");
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_follow_what_the_paths_depend_on_and_ignore_the_paintable_colour() {
        let file = SceneFile::default_scene();
        let keys = SceneKeys::of(&file).unwrap();
        assert_eq!(keys, SceneKeys::of(&file.clone()).unwrap(), "deterministic");

        let mut recoloured = file.clone();
        let [Some(MaterialDesc::Fiber(mut warp)), weft] = file.material_slots() else {
            panic!("fiber yarns")
        };
        warp.c_tt = Rgb::new(0.9, 0.1, 0.1);
        recoloured.materials.warp = Some(MaterialDesc::Fiber(warp));
        recoloured.materials.weft = weft;
        assert!(
            keys.differences(&SceneKeys::of(&recoloured).unwrap()).is_empty(),
            "C_TT is painted, not traced"
        );

        warp.c_r = Rgb::splat(0.2);
        recoloured.materials.warp = Some(MaterialDesc::Fiber(warp));
        assert_eq!(
            keys.differences(&SceneKeys::of(&recoloured).unwrap()),
            ["the cloth (fabric, swatch, or a yarn material other than its paintable colour)"]
        );

        let mut moved = file.clone();
        moved.camera.eye[0] += 0.1;
        moved.lights.pop();
        assert_eq!(keys.differences(&SceneKeys::of(&moved).unwrap()), ["the camera", "the lights"]);
        let mut other_swatch = file.clone();
        other_swatch.swatch.ground = !other_swatch.swatch.ground;
        assert_eq!(keys.differences(&SceneKeys::of(&other_swatch).unwrap()).len(), 1);
    }
}
