//! `twill colorways`: a set of named colourways of one scene rendered to images and a contact
//! sheet, for a designer to send out.
//!
//! How it works: the colourways file (TOML) lists `[[colorway]]` entries, each a name and what
//! `[materials]` takes for a colourway (`warp_order`, `weft_order`, `[colorway.palette]`; see
//! docs/SCENE_FORMAT.md). Each replaces the scene's colourway (the scene's `warp` and `weft`
//! yarns stay the palette's bases), is checked as a scene would be (an error names the file and
//! the colourway), and is rendered: on the GPU after a bake through the stage cache (colourways
//! of one weave share every geometry stage, so only the material stages rebake, and the bake is
//! written into the one renderer in place where its layout allows), or path traced
//! with `--reference`. Every image is written as PNG (and EXR with `--exr`) under the output
//! folder, named by its position and name; `contact-sheet.png` sets them side by side with
//! their names beneath (egui's Ubuntu Light, drawn with ab_glyph). Writes are atomic.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
use anyhow::{Context, Result, bail, ensure};
use glam::Vec3;
use twill_precompute::bake::pipeline::Baked;
use twill_precompute::bake::settings::Quality;
use twill_precompute::image::Image;
use twill_precompute::pathtrace::{self, Component, RenderSettings};
use twill_precompute::scene::{PaletteColour, SceneFile};
use twill_renderer::export::{Display, display_srgb8, write_display_png, write_image};
use twill_renderer::headless::{SceneRenderer, frame_settings};
use twill_renderer::plan::Components;

/// The most colourways one file may list.
pub const MAX_COLORWAYS: usize = 64;
/// Largest side of a thumbnail on the contact sheet, pixels.
const THUMBNAIL_SIDE: usize = 256;
/// Height of the name strip under each thumbnail, pixels.
const LABEL_HEIGHT: usize = 30;
/// Gap between thumbnails, pixels.
const GAP: usize = 8;

/// Options of `twill colorways`.
pub struct ColorwaysOptions {
    pub scene: Option<PathBuf>,
    pub from: PathBuf,
    pub output_dir: PathBuf,
    pub size: Option<(usize, usize)>,
    pub spp: Option<u32>,
    pub quality: Quality,
    pub reference: bool,
    pub exr: bool,
    pub cache: Option<PathBuf>,
    pub no_cache: bool,
}

/// The colourways file.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ColorwaysFile {
    colorway: Vec<ColorwayEntry>,
}

/// One `[[colorway]]`.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ColorwayEntry {
    name: String,
    warp_order: String,
    weft_order: String,
    palette: BTreeMap<String, PaletteColour>,
}

/// A rendered colourway: its name, files and display pixels.
struct Rendered {
    name: String,
    files: Vec<PathBuf>,
    width: usize,
    height: usize,
    rgba: Vec<[u8; 4]>,
    seconds: f64,
}

/// Reads and checks the colourways file against the scene: each entry becomes the scene with
/// that colourway.
fn read_colorways(path: &Path, base: &SceneFile) -> Result<Vec<(String, SceneFile)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("{}: cannot be read", path.display()))?;
    let file: ColorwaysFile =
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    ensure!(
        (1..=MAX_COLORWAYS).contains(&file.colorway.len()),
        "{}: {} colourways; 1 to {MAX_COLORWAYS} `[[colorway]]` entries are rendered",
        path.display(),
        file.colorway.len()
    );
    let mut out: Vec<(String, SceneFile)> = Vec::with_capacity(file.colorway.len());
    for (k, entry) in file.colorway.into_iter().enumerate() {
        let name = entry.name.trim().to_owned();
        let place = format!("{}: colorway {} ({name:?})", path.display(), k + 1);
        ensure!(!name.is_empty(), "{place}: the name is empty");
        ensure!(!out.iter().any(|(n, _)| *n == name), "{place}: the name is used twice");
        let mut scene = base.clone();
        scene.materials.palette = entry.palette;
        scene.materials.warp_order = Some(entry.warp_order);
        scene.materials.weft_order = Some(entry.weft_order);
        scene.check_colourway().map_err(|e| anyhow::anyhow!("{place}: {e}"))?;
        out.push((name, scene));
    }
    Ok(out)
}

/// A file name for colourway `index` called `name`: its number, then the name's letters and
/// digits (other characters as `-`).
fn file_stem(index: usize, name: &str) -> String {
    let slug: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '-' })
        .collect::<String>()
        .split('-')
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join("-");
    format!("{:02}-{}", index + 1, if slug.is_empty() { "colorway" } else { &slug })
}

/// `twill colorways`.
pub fn colorways(options: &ColorwaysOptions) -> Result<()> {
    let mut base = SceneFile::load_or_default(options.scene.as_deref())?;
    if let Some((w, h)) = options.size {
        (base.render.width, base.render.height) = (w, h);
    }
    base.render.spp = options.spp.unwrap_or(base.render.spp);
    let entries = read_colorways(&options.from, &base)?;
    std::fs::create_dir_all(&options.output_dir)
        .with_context(|| format!("{}: the output folder cannot be made", options.output_dir.display()))?;
    let cache = crate::commands::open_cache(options.cache.as_deref(), options.no_cache)?;
    // One renderer for every colourway: a recolouring is written into it in place.
    let mut session: Option<SceneRenderer> = None;
    let mut rendered = Vec::with_capacity(entries.len());
    for (index, (name, file)) in entries.iter().enumerate() {
        let started = Instant::now();
        let mut scene = file.build()?;
        if options.reference {
            twill_renderer::headless::trace_on_mesh(&mut scene)?;
        }
        let stem = options.output_dir.join(file_stem(index, name));
        let display = Display { exposure: scene.render.exposure, ..Display::default() };
        let (width, height) = (scene.render.width, scene.render.height);
        let (image, rgba) = if options.reference {
            let camera = twill_precompute::scene::camera_from(&scene.camera, width, height)?;
            let settings = RenderSettings {
                spp: scene.render.spp,
                max_depth: scene.render.max_depth,
                component: Component::All,
                seed: scene.render.seed,
            };
            let image = pathtrace::render(&scene.path_scene, &camera, &settings, &|_| {}).mean();
            let rgba = image.pixels.iter().map(|p| rgba_of(display_srgb8(*p, display))).collect();
            (image, rgba)
        } else {
            let (exemplars, pattern) =
                crate::commands::bake_scene(&scene, options.quality.settings(), cache.as_ref())?;
            let refs: Vec<&Baked> = exemplars.iter().collect();
            let (mut uploaded, _) = crate::commands::upload_to(session.take(), &scene, &refs, &pattern)?;
            let frame = uploaded.render(&scene, &frame_settings(&scene, Components::All))?;
            session = Some(uploaded);
            let image = Image {
                width,
                height,
                pixels: frame.radiance.iter().map(|p| Vec3::from(*p).as_dvec3()).collect(),
            };
            (image, frame.display)
        };
        let png = stem.with_extension("png");
        write_display_png(&png, width as u32, height as u32, &rgba)?;
        let mut files = vec![png];
        if options.exr {
            let exr = stem.with_extension("exr");
            write_image(&exr, &image, display)?;
            files.push(exr);
        }
        let seconds = started.elapsed().as_secs_f64();
        eprintln!("{}/{}: {name} ({seconds:.1} s)", index + 1, entries.len());
        rendered.push(Rendered { name: name.clone(), files, width, height, rgba, seconds });
    }
    let sheet = options.output_dir.join("contact-sheet.png");
    let (width, height, pixels) = contact_sheet(&rendered)?;
    write_display_png(&sheet, width as u32, height as u32, &pixels)?;
    println!("| colourway | files | seconds |\n|---|---|---|");
    for r in &rendered {
        let files: Vec<String> = r.files.iter().map(|f| f.display().to_string()).collect();
        println!("| {} | {} | {:.1} |", r.name, files.join(", "), r.seconds);
    }
    println!("contact sheet: {}", sheet.display());
    Ok(())
}

fn rgba_of([r, g, b]: [u8; 3]) -> [u8; 4] {
    [r, g, b, 255]
}

/// The contact sheet: thumbnails (box-filtered to at most [`THUMBNAIL_SIDE`]) in a grid of
/// about square shape, each with its name beneath, on a dark background.
fn contact_sheet(rendered: &[Rendered]) -> Result<(usize, usize, Vec<[u8; 4]>)> {
    let font = FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT).context("egui's font loads")?;
    let thumbnails: Vec<(usize, usize, Vec<[u8; 4]>)> = rendered.iter().map(thumbnail).collect();
    let cell_w = thumbnails.iter().map(|t| t.0).max().unwrap_or(1);
    let cell_h = thumbnails.iter().map(|t| t.1).max().unwrap_or(1) + LABEL_HEIGHT;
    let columns = (rendered.len() as f64).sqrt().ceil().max(1.0) as usize;
    let rows = rendered.len().div_ceil(columns);
    let width = GAP + columns * (cell_w + GAP);
    let height = GAP + rows * (cell_h + GAP);
    if width * height > 1 << 28 {
        bail!("the contact sheet would be {width} x {height} pixels");
    }
    let mut pixels = vec![[24, 24, 24, 255]; width * height];
    for (k, ((tw, th, thumb), r)) in thumbnails.iter().zip(rendered).enumerate() {
        let (x0, y0) = (GAP + (k % columns) * (cell_w + GAP), GAP + (k / columns) * (cell_h + GAP));
        for y in 0..*th {
            let row = (y0 + y) * width + x0;
            pixels[row..row + tw].copy_from_slice(&thumb[y * tw..(y + 1) * tw]);
        }
        draw_label(&font, &r.name, (x0, y0 + th + 6), cell_w, &mut pixels, width);
    }
    Ok((width, height, pixels))
}

/// The image box-filtered down by the smallest whole factor that fits [`THUMBNAIL_SIDE`].
fn thumbnail(r: &Rendered) -> (usize, usize, Vec<[u8; 4]>) {
    let factor = r.width.max(r.height).div_ceil(THUMBNAIL_SIDE).max(1);
    let (w, h) = ((r.width / factor).max(1), (r.height / factor).max(1));
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let mut sum = [0_u32; 4];
            let mut n = 0;
            for sy in y * factor..((y + 1) * factor).min(r.height) {
                for sx in x * factor..((x + 1) * factor).min(r.width) {
                    let p = r.rgba[sy * r.width + sx];
                    for c in 0..4 {
                        sum[c] += u32::from(p[c]);
                    }
                    n += 1;
                }
            }
            out.push(sum.map(|s| (s / n.max(1)) as u8));
        }
    }
    (w, h, out)
}

/// `text` in light gray at `(x, top)`, cut with an ellipsis to `max_width` pixels.
fn draw_label(
    font: &FontRef<'_>,
    text: &str,
    (x, top): (usize, usize),
    max_width: usize,
    pixels: &mut [[u8; 4]],
    width: usize,
) {
    let scale = PxScale::from(18.0);
    let scaled = font.as_scaled(scale);
    let advance = |s: &str| s.chars().map(|c| scaled.h_advance(font.glyph_id(c))).sum::<f32>();
    let mut shown: String = text.to_owned();
    if advance(&shown) > max_width as f32 {
        while !shown.is_empty() && advance(&format!("{shown}…")) > max_width as f32 {
            shown.pop();
        }
        shown.push('…');
    }
    let height = pixels.len() / width;
    let baseline = top as f32 + scaled.ascent();
    let mut pen = x as f32;
    for c in shown.chars() {
        let id = font.glyph_id(c);
        let glyph = id.with_scale_and_position(scale, ab_glyph::point(pen, baseline));
        pen += scaled.h_advance(id);
        let Some(outlined) = font.outline_glyph(glyph) else { continue };
        let bounds = outlined.px_bounds();
        outlined.draw(|gx, gy, coverage| {
            let (px, py) = (bounds.min.x as i64 + i64::from(gx), bounds.min.y as i64 + i64::from(gy));
            if px < 0 || py < 0 || px as usize >= width || py as usize >= height {
                return;
            }
            let p = &mut pixels[py as usize * width + px as usize];
            for channel in &mut p[..3] {
                let ink = 230.0;
                *channel =
                    (f32::from(*channel) + (ink - f32::from(*channel)) * coverage.clamp(0.0, 1.0)) as u8;
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO: &str = "[[colorway]]\nname = \"Navy stripe\"\nwarp_order = \"2 navy, 2 cream\"\nweft_order = \"cream\"\n\
        [colorway.palette]\nnavy = { base = \"warp\", c_tt = [0.05, 0.07, 0.3] }\ncream = { base = \"weft\" }\n\
        [[colorway]]\nname = \"Red\"\nwarp_order = \"red\"\nweft_order = \"red\"\n\
        [colorway.palette]\nred = { base = \"warp\", c_tt = [0.8, 0.1, 0.08] }\n";

    fn write(dir: &Path, text: &str) -> PathBuf {
        let path = dir.join("colorways.toml");
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn colorway_files_are_read_and_checked_against_the_scene() {
        let dir = tempfile::tempdir().unwrap();
        let base = SceneFile::default_scene();
        let entries = read_colorways(&write(dir.path(), TWO), &base).unwrap();
        assert_eq!(entries.len(), 2);
        assert_eq!(entries[0].0, "Navy stripe");
        assert_eq!(entries[1].1.build().unwrap().material_descs.len(), 1);
        for (text, expect) in [
            (TWO.replace("2 navy, 2 cream", "2 teal"), "colorway 1 (\"Navy stripe\"): warp_order run 1"),
            (TWO.replace("name = \"Red\"", "name = \"Navy stripe\""), "used twice"),
            (TWO.replace("name = \"Red\"", "name = \" \""), "the name is empty"),
            (TWO.replace("weft_order = \"red\"", "weft_order = \"red\"\nsize = 3"), "unknown field `size`"),
            ("colorway = []\n".to_owned(), "1 to 64"),
        ] {
            let message = read_colorways(&write(dir.path(), &text), &base).unwrap_err().to_string();
            assert!(message.contains(expect) && message.contains("colorways.toml"), "{expect}: {message}");
        }
    }

    #[test]
    fn file_names_keep_the_order_and_the_names_letters() {
        assert_eq!(file_stem(0, "Navy stripe"), "01-navy-stripe");
        assert_eq!(file_stem(11, "Rouge / Crème #2"), "12-rouge-cr-me-2");
        assert_eq!(file_stem(2, "???"), "03-colorway");
    }

    #[test]
    fn the_contact_sheet_holds_every_thumbnail_and_its_name() {
        let make = |name: &str, colour: [u8; 4]| Rendered {
            name: name.into(),
            files: Vec::new(),
            width: 600,
            height: 300,
            rgba: vec![colour; 600 * 300],
            seconds: 0.0,
        };
        let rendered =
            [make("Navy", [0, 0, 128, 255]), make("A very long name that does not fit", [200, 0, 0, 255])];
        let (width, height, pixels) = contact_sheet(&rendered).unwrap();
        // Two thumbnails of 200 x 100 (factor 3), side by side, names beneath.
        assert_eq!((width, height), (GAP + 2 * (200 + GAP), GAP + 100 + LABEL_HEIGHT + GAP));
        assert_eq!(pixels[(GAP + 50) * width + GAP + 100], [0, 0, 128, 255]);
        assert_eq!(pixels[(GAP + 50) * width + 2 * GAP + 200 + 100], [200, 0, 0, 255]);
        // Ink in both name strips, and none past the second cell's width.
        let ink = |x0: usize, x1: usize| {
            (GAP + 100..GAP + 100 + LABEL_HEIGHT)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .filter(|&(x, y)| pixels[y * width + x][0] > 100)
                .count()
        };
        assert!(ink(GAP, GAP + 200) > 20);
        assert!(ink(2 * GAP + 200, 2 * GAP + 400) > 20);
        assert_eq!(ink(2 * GAP + 400, width), 0);
    }

    #[test]
    fn path_traced_colorways_are_written_with_their_contact_sheet() {
        let dir = tempfile::tempdir().unwrap();
        let options = ColorwaysOptions {
            scene: None,
            from: write(dir.path(), TWO),
            output_dir: dir.path().join("out"),
            size: Some((24, 16)),
            spp: Some(1),
            quality: Quality::Draft,
            reference: true,
            exr: true,
            cache: None,
            no_cache: true,
        };
        colorways(&options).unwrap();
        for name in
            ["01-navy-stripe.png", "01-navy-stripe.exr", "02-red.png", "02-red.exr", "contact-sheet.png"]
        {
            assert!(dir.path().join("out").join(name).is_file(), "{name}");
        }
        let decoder = png::Decoder::new(std::io::BufReader::new(
            std::fs::File::open(dir.path().join("out/contact-sheet.png")).unwrap(),
        ));
        let info = decoder.read_info().unwrap().info().clone();
        assert_eq!(
            (info.width as usize, info.height as usize),
            (GAP + 2 * (24 + GAP), GAP + 16 + LABEL_HEIGHT + GAP)
        );

        // Patterned cloth takes colour orders, and the path tracer draws its blocks.
        let patterned = dir.path().join("patterned.toml");
        std::fs::copy(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/patterned.toml"),
            &patterned,
        )
        .unwrap();
        let output_dir = dir.path().join("patterned");
        colorways(&ColorwaysOptions { scene: Some(patterned), output_dir: output_dir.clone(), ..options })
            .unwrap();
        for name in ["01-navy-stripe.png", "02-red.png", "contact-sheet.png"] {
            assert!(output_dir.join(name).is_file(), "{name}");
        }
    }
}
