//! Viewer scripts: a list of edits and checks the viewer plays back through the same code
//! paths as the panels, for tests that run the real window (`twill view --script FILE`).
//!
//! How it works: [`parse_script`] reads one command per line (`#` starts a comment) into
//! [`Step`]s, with the line number in every error. The viewer runs one step per frame; waiting
//! steps (`wait-fabric`, `wait-spp`, `wait-export`, `expect-error`, `screenshot`, `lose-device`,
//! `wait-paint`, `wait-verify`) hold the script until their condition holds, each for at most [`STEP_TIMEOUT`]. An error the viewer
//! shows while a script runs fails the script unless an `expect-error` step is waiting for it.
//! When the script ends (`quit`, or its last line) the window closes; a failed script makes
//! `twill view` exit with an error naming the line.
//!
//! Commands:
//!
//! ```text
//! wait-fabric draft|interactive|paper   # until that bake's picture is on screen
//! expect-baking draft|interactive|paper # fails unless a bake of that quality is in flight now
//! bake draft|interactive|paper          # start a bake (cancels the one in flight)
//! cancel-bake
//! orbit DYAW DPITCH                     # degrees
//! zoom FACTOR                           # < 1 zooms in
//! fit                                   # fit the fabric to the view
//! light INDEX azimuth|elevation|sharpness|intensity VALUE
//! light INDEX colour R G B
//! add-light directional|sg
//! remove-light INDEX
//! preset NAME                           # an environment preset, e.g. preset sunset
//! set exposure|spp|sigma-glo|interaction-scale VALUE
//! wait-spp N                            # until the picture has N samples at full size, tone
//!                                       # mapped as set (it fails if it has more: `set spp N` first)
//! screenshot PATH.png                   # the window; the viewport alone goes to PATH.viewport.png
//! export PATH WxH SPP                   # an off-screen export (PNG or EXR, with its TOML)
//! wait-export                           # until the export is written
//! expect-error TEXT                     # until an error containing TEXT is shown
//! flip ROW COL                          # flip a crossing of the weave draft (pick, end)
//! weave PRESET                          # a weave preset, e.g. weave twill_2_2
//! repeat PICKS ENDS                     # the draft's repeat size
//! import-wif PATH                       # the draft (and colours, if any) of a WIF file
//! palette NAME warp|weft R G B          # add or recolour a palette colour (linear RGB)
//! order warp|weft RUNS...               # a colour order, e.g. order warp 2 navy, 1 red
//! fiber warp|weft beta_r|beta_tt|gamma_tt DEGREES
//! fiber warp|weft c_r|c_tt R G B
//! mesh builtin swatch|drape|cushion
//! mesh file PATH                        # an OBJ or glTF surface
//! mesh thickness SCALE
//! undo
//! redo
//! save PATH                             # the scene as shown, in the CLI's format
//! open PATH                             # another scene
//! wait-idle                             # until no bake runs and the latest one is on screen
//! spin SECONDS                          # orbit a little every frame (a user dragging)
//! frame-times PATH                      # the UI frame times so far, as text; then forget them
//! lose-device                           # destroy the render device (a simulated loss) and wait
//!                                       # until the viewer renders on a new one
//! wait-recolour-picture                 # until a colour edit's first picture is on screen; prints
//!                                       # the time from the edit to it
//! paint-start SIDE SPP [VERIFY_SPP]     # paint mode: freeze the view, precompute a paint image
//!                                       # SIDE pixels along its longer side at SPP paths (and
//!                                       # verify later at VERIFY_SPP samples per pixel)
//! wait-paint                            # until paint mode's precompute is done
//! paint-colour R G B                    # the brush colour (linear RGB)
//! paint-scope section|thread|set        # what a click paints
//! paint-at X Y                          # click at (X, Y), fractions of the paint image (0-1)
//! paint-pick X Y                        # take the colour of the yarn at (X, Y)
//! paint-undo
//! paint-commit                          # the painting as colour orders; leaves paint mode and
//!                                       # queues a verification
//! paint-verify                          # path-trace the painted cloth to check the painting
//! wait-verify                           # until the verification is done (its report is printed)
//! paint-save PATH.toml                  # the painting as strokes (`twill paint` reads them)
//! paint-open PATH.toml                  # paint a painting file's strokes
//! paint-save-data PATH.twillpaint       # the precompute, for `twill paint apply|verify|commit`
//! paint-show painting|reference|difference  # after a verification: what the viewport shows
//! paint-leave                           # (paint-start on the same view resumes the painting)
//! quit
//! ```

use std::path::{Path, PathBuf};
use std::time::Duration;

use twill_precompute::bake::settings::Quality;

use twill_precompute::scene::YarnSlot;

use super::fabric::FiberField;

/// `warp` or `weft`.
fn yarn_slot(word: Option<&str>) -> Result<YarnSlot, String> {
    match word {
        Some("warp") => Ok(YarnSlot::Warp),
        Some("weft") => Ok(YarnSlot::Weft),
        other => Err(format!("expected warp or weft, not {other:?}")),
    }
}
use super::app::PaintFileAction;
use super::lights::LightKind;
use super::paint::{Scope, Shown};

/// Longest a waiting step may wait.
pub const STEP_TIMEOUT: Duration = Duration::from_mins(5);

/// A light property a script sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightField {
    Azimuth(f64),
    Elevation(f64),
    Sharpness(f64),
    Intensity(f64),
    Colour([f32; 3]),
}

/// A viewer setting a script sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Setting {
    Exposure(f64),
    Spp(u32),
    SigmaGlo(f64),
    InteractionScale(f64),
}

/// One command.
#[derive(Debug, Clone, PartialEq)]
pub enum Step {
    WaitFabric(Quality),
    ExpectBaking(Quality),
    Bake(Quality),
    CancelBake,
    Orbit { yaw_deg: f64, pitch_deg: f64 },
    Zoom(f64),
    Fit,
    Light { index: usize, field: LightField },
    AddLight(LightKind),
    RemoveLight(usize),
    Preset(String),
    Set(Setting),
    WaitSpp(u32),
    Screenshot(PathBuf),
    Export { path: PathBuf, width: u32, height: u32, spp: u32 },
    WaitExport,
    ExpectError(String),
    Flip { row: usize, col: usize },
    Weave(String),
    Repeat { rows: usize, cols: usize },
    ImportWif(PathBuf),
    Palette { name: String, base: YarnSlot, rgb: [f64; 3] },
    Order { slot: YarnSlot, text: String },
    Fiber { slot: usize, field: FiberField },
    Mesh(MeshEdit),
    Undo,
    Redo,
    Save(PathBuf),
    Open(PathBuf),
    WaitIdle,
    Spin(f64),
    FrameTimes(PathBuf),
    LoseDevice,
    WaitRecolourPicture,
    PaintStart { side: u32, spp: u32, verify_spp: Option<u32> },
    WaitPaint,
    PaintColour([f32; 3]),
    PaintScope(Scope),
    PaintAt { x: f64, y: f64 },
    PaintPick { x: f64, y: f64 },
    PaintUndo,
    PaintCommit,
    PaintVerify,
    WaitVerify,
    PaintLeave,
    PaintFile { action: PaintFileAction, path: PathBuf },
    PaintShow(Shown),
    Quit,
}

/// A mesh edit a script makes.
#[derive(Debug, Clone, PartialEq)]
pub enum MeshEdit {
    Builtin(String),
    File(PathBuf),
    Thickness(f64),
}

/// A step and the line it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct ScriptLine {
    pub line: usize,
    pub text: String,
    pub step: Step,
}

fn number<T: std::str::FromStr>(word: Option<&str>, what: &str) -> Result<T, String> {
    let word = word.ok_or_else(|| format!("missing {what}"))?;
    word.parse().map_err(|_| format!("{word:?} is not a valid {what}"))
}

fn finite(value: f64, what: &str) -> Result<f64, String> {
    if value.is_finite() { Ok(value) } else { Err(format!("{what} must be finite")) }
}

fn parse_step(words: &[&str]) -> Result<Step, String> {
    let mut args = words[1..].iter().copied();
    let quality = |word: Option<&str>| match word {
        Some("draft") => Ok(Quality::Draft),
        Some("interactive") => Ok(Quality::Interactive),
        Some("paper") => Ok(Quality::Paper),
        other => Err(format!("{} takes draft, interactive or paper, not {other:?}", words[0])),
    };
    let step = match words[0] {
        "wait-fabric" => Step::WaitFabric(quality(args.next())?),
        "expect-baking" => Step::ExpectBaking(quality(args.next())?),
        "bake" => Step::Bake(quality(args.next())?),
        "cancel-bake" => Step::CancelBake,
        "orbit" => Step::Orbit {
            yaw_deg: finite(number(args.next(), "yaw in degrees")?, "yaw")?,
            pitch_deg: finite(number(args.next(), "pitch in degrees")?, "pitch")?,
        },
        "zoom" => {
            let factor: f64 = number(args.next(), "zoom factor")?;
            if !(factor.is_finite() && factor > 0.0) {
                return Err("the zoom factor must be positive".into());
            }
            Step::Zoom(factor)
        }
        "fit" => Step::Fit,
        "light" => {
            let index = number(args.next(), "light index")?;
            let property = args.next().ok_or("missing light property")?;
            let field = match property {
                "azimuth" => LightField::Azimuth(finite(number(args.next(), "azimuth")?, "azimuth")?),
                "elevation" => LightField::Elevation(finite(number(args.next(), "elevation")?, "elevation")?),
                "sharpness" => LightField::Sharpness(finite(number(args.next(), "sharpness")?, "sharpness")?),
                "intensity" => LightField::Intensity(finite(number(args.next(), "intensity")?, "intensity")?),
                "colour" | "color" => LightField::Colour([
                    number(args.next(), "red")?,
                    number(args.next(), "green")?,
                    number(args.next(), "blue")?,
                ]),
                other => return Err(format!("unknown light property {other:?}")),
            };
            Step::Light { index, field }
        }
        "add-light" => Step::AddLight(match args.next() {
            Some("directional") => LightKind::Directional,
            Some("sg") => LightKind::Sg,
            other => return Err(format!("add-light takes directional or sg, not {other:?}")),
        }),
        "remove-light" => Step::RemoveLight(number(args.next(), "light index")?),
        "preset" => {
            let name = words[1..].join(" ");
            if name.is_empty() {
                return Err("missing preset name".into());
            }
            args = [].iter().copied();
            Step::Preset(name)
        }
        "set" => {
            let key = args.next().ok_or("missing setting name")?;
            Step::Set(match key {
                "exposure" => Setting::Exposure(finite(number(args.next(), "exposure")?, "exposure")?),
                "spp" => Setting::Spp(number(args.next(), "sample count")?),
                "sigma-glo" => Setting::SigmaGlo(finite(number(args.next(), "sigma_glo")?, "sigma_glo")?),
                "interaction-scale" => {
                    Setting::InteractionScale(finite(number(args.next(), "scale")?, "interaction scale")?)
                }
                other => return Err(format!("unknown setting {other:?}")),
            })
        }
        "wait-spp" => Step::WaitSpp(number(args.next(), "sample count")?),
        "screenshot" => Step::Screenshot(PathBuf::from(args.next().ok_or("missing screenshot file")?)),
        "export" => {
            let path = PathBuf::from(args.next().ok_or("missing export file")?);
            let size = args.next().ok_or("missing export size WxH")?;
            let (w, h) = crate::commands::parse_size(size)?;
            Step::Export {
                path,
                width: w as u32,
                height: h as u32,
                spp: number(args.next(), "sample count")?,
            }
        }
        "wait-export" => Step::WaitExport,
        "expect-error" => {
            let text = words[1..].join(" ");
            args = [].iter().copied();
            Step::ExpectError(text)
        }
        "flip" => {
            Step::Flip { row: number(args.next(), "pick (row)")?, col: number(args.next(), "end (column)")? }
        }
        "weave" => Step::Weave(args.next().ok_or("missing weave preset")?.to_owned()),
        "repeat" => {
            Step::Repeat { rows: number(args.next(), "pick count")?, cols: number(args.next(), "end count")? }
        }
        "import-wif" => Step::ImportWif(PathBuf::from(args.next().ok_or("missing WIF file")?)),
        "palette" => {
            let name = args.next().ok_or("missing colour name")?.to_owned();
            let base = yarn_slot(args.next())?;
            let rgb =
                [number(args.next(), "red")?, number(args.next(), "green")?, number(args.next(), "blue")?];
            Step::Palette { name, base, rgb }
        }
        "order" => {
            let slot = yarn_slot(args.next())?;
            let text = args.by_ref().collect::<Vec<_>>().join(" ");
            if text.is_empty() {
                return Err("missing colour order, e.g. order warp 2 navy, 1 red".into());
            }
            Step::Order { slot, text }
        }
        "fiber" => {
            let slot = match args.next() {
                Some("warp") => 0,
                Some("weft") => 1,
                other => return Err(format!("fiber takes warp or weft, not {other:?}")),
            };
            let colour = |args: &mut dyn Iterator<Item = &str>| -> Result<[f64; 3], String> {
                Ok([number(args.next(), "red")?, number(args.next(), "green")?, number(args.next(), "blue")?])
            };
            let field = match args.next() {
                Some("beta_r") => FiberField::BetaR(finite(number(args.next(), "beta_r")?, "beta_r")?),
                Some("beta_tt") => FiberField::BetaTt(finite(number(args.next(), "beta_tt")?, "beta_tt")?),
                Some("gamma_tt") => {
                    FiberField::GammaTt(finite(number(args.next(), "gamma_tt")?, "gamma_tt")?)
                }
                Some("c_r") => FiberField::ColourR(colour(&mut args)?),
                Some("c_tt") => FiberField::ColourTt(colour(&mut args)?),
                other => return Err(format!("unknown fiber parameter {other:?}")),
            };
            Step::Fiber { slot, field }
        }
        "mesh" => Step::Mesh(match args.next() {
            Some("builtin") => MeshEdit::Builtin(args.next().ok_or("missing built-in mesh name")?.to_owned()),
            Some("file") => MeshEdit::File(PathBuf::from(args.next().ok_or("missing mesh file")?)),
            Some("thickness") => {
                MeshEdit::Thickness(finite(number(args.next(), "thickness scale")?, "thickness")?)
            }
            other => return Err(format!("mesh takes builtin, file or thickness, not {other:?}")),
        }),
        "undo" => Step::Undo,
        "redo" => Step::Redo,
        "save" => Step::Save(PathBuf::from(args.next().ok_or("missing scene file")?)),
        "open" => Step::Open(PathBuf::from(args.next().ok_or("missing scene file")?)),
        "wait-idle" => Step::WaitIdle,
        "spin" => {
            let seconds: f64 = number(args.next(), "duration in seconds")?;
            if !(seconds.is_finite() && seconds > 0.0 && seconds <= 600.0) {
                return Err("spin takes 0 < seconds <= 600".into());
            }
            Step::Spin(seconds)
        }
        "frame-times" => Step::FrameTimes(PathBuf::from(args.next().ok_or("missing output file")?)),
        "lose-device" => Step::LoseDevice,
        "wait-recolour-picture" => Step::WaitRecolourPicture,
        "paint-start" => {
            let side: u32 = number(args.next(), "paint image side")?;
            let spp: u32 = number(args.next(), "paths per pixel")?;
            let verify_spp: Option<u32> =
                args.next().map(|w| number(Some(w), "verification spp")).transpose()?;
            let counts = [Some(spp), verify_spp].into_iter().flatten();
            if !(8..=4096).contains(&side) || !counts.into_iter().all(|n| (1..=1_048_576).contains(&n)) {
                return Err("paint-start takes 8 <= SIDE <= 4096 and sample counts from 1 to 1048576".into());
            }
            Step::PaintStart { side, spp, verify_spp }
        }
        "wait-paint" => Step::WaitPaint,
        "paint-colour" | "paint-color" => {
            let rgb: [f32; 3] =
                [number(args.next(), "red")?, number(args.next(), "green")?, number(args.next(), "blue")?];
            if !rgb.iter().all(|c| (0.0..=1.0).contains(c)) {
                return Err("paint colours are linear RGB from 0 to 1".into());
            }
            Step::PaintColour(rgb)
        }
        "paint-scope" => Step::PaintScope(Scope::parse(args.next().ok_or("missing paint scope")?)?),
        "paint-at" | "paint-pick" => {
            let x: f64 = number(args.next(), "x (fraction of the image)")?;
            let y: f64 = number(args.next(), "y (fraction of the image)")?;
            if !((0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y)) {
                return Err("paint positions are fractions of the paint image, 0 to 1".into());
            }
            if words[0] == "paint-at" { Step::PaintAt { x, y } } else { Step::PaintPick { x, y } }
        }
        "paint-undo" => Step::PaintUndo,
        "paint-commit" => Step::PaintCommit,
        "paint-verify" => Step::PaintVerify,
        "wait-verify" => Step::WaitVerify,
        "paint-leave" => Step::PaintLeave,
        "paint-show" => Step::PaintShow(Shown::parse(args.next().ok_or("missing what to show")?)?),
        "paint-save" | "paint-open" | "paint-save-data" => {
            let action = match words[0] {
                "paint-save" => PaintFileAction::SavePainting,
                "paint-open" => PaintFileAction::OpenPainting,
                _ => PaintFileAction::SavePaintFile,
            };
            Step::PaintFile { action, path: PathBuf::from(args.next().ok_or("missing file")?) }
        }
        "quit" => Step::Quit,
        other => return Err(format!("unknown command {other:?}")),
    };
    if let Some(extra) = args.next() {
        return Err(format!("unexpected {extra:?} after the command"));
    }
    Ok(step)
}

/// Parses a script; errors name the file and line.
pub fn parse_script(text: &str, path: &Path) -> Result<Vec<ScriptLine>, String> {
    let mut steps = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let words: Vec<&str> = content.split_whitespace().collect();
        let step = parse_step(&words).map_err(|e| format!("{}:{}: {e}", path.display(), i + 1))?;
        steps.push(ScriptLine { line: i + 1, text: content.to_owned(), step });
    }
    Ok(steps)
}

/// The file the viewport alone is written to beside a window screenshot.
#[must_use]
pub fn viewport_screenshot_path(window: &Path) -> PathBuf {
    let stem = window.file_stem().map_or_else(|| "screenshot".into(), |s| s.to_string_lossy().into_owned());
    window.with_file_name(format!("{stem}.viewport.png"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_command_parses() {
        let text = "# comment\nwait-fabric draft\nbake paper\ncancel-bake\norbit 20 -5\nzoom 0.8\nfit\nlight 0 azimuth 120 # trailing\n\
                    light 1 colour 1 0.5 0.25\nadd-light sg\nremove-light 2\npreset studio three-point\n\
                    set spp 8\nwait-spp 8\nscreenshot out.png\nexport shot.exr 64x48 4\nwait-export\n\
                    expect-error unknown preset\nquit\n";
        let steps = parse_script(text, Path::new("s.txt")).unwrap();
        assert_eq!(steps.len(), 18);
        assert_eq!(steps[0].line, 2);
        assert_eq!(steps[1].step, Step::Bake(Quality::Paper));
        assert_eq!(steps[6].step, Step::Light { index: 0, field: LightField::Azimuth(120.0) });
        assert_eq!(steps[10].step, Step::Preset("studio three-point".into()));
        assert_eq!(steps[14].step, Step::Export { path: "shot.exr".into(), width: 64, height: 48, spp: 4 });
        assert_eq!(steps[16].step, Step::ExpectError("unknown preset".into()));
    }

    #[test]
    fn the_editing_commands_parse() {
        let text = "flip 1 2\nweave satin_4_1\nrepeat 4 6\nimport-wif a.wif\nfiber weft beta_tt 12.5\n\
                    fiber warp c_r 0.1 0.2 0.3\nmesh builtin cushion\nmesh file m.obj\nmesh thickness 2\n\
                    undo\nredo\nsave s.toml\nopen s.toml\nwait-idle\nspin 2.5\nframe-times t.txt\nlose-device\n\
                    expect-baking interactive\npalette navy warp 0.05 0.07 0.3\norder weft 2 cream, 1 navy\n";
        let steps: Vec<Step> =
            parse_script(text, Path::new("s.txt")).unwrap().into_iter().map(|l| l.step).collect();
        assert_eq!(steps[0], Step::Flip { row: 1, col: 2 });
        assert_eq!(steps[2], Step::Repeat { rows: 4, cols: 6 });
        assert_eq!(steps[4], Step::Fiber { slot: 1, field: FiberField::BetaTt(12.5) });
        assert_eq!(steps[5], Step::Fiber { slot: 0, field: FiberField::ColourR([0.1, 0.2, 0.3]) });
        assert_eq!(steps[8], Step::Mesh(MeshEdit::Thickness(2.0)));
        assert_eq!(steps[14], Step::Spin(2.5));
        assert_eq!(steps[16], Step::LoseDevice);
        assert_eq!(steps[17], Step::ExpectBaking(Quality::Interactive));
        assert_eq!(
            steps[18],
            Step::Palette { name: "navy".into(), base: YarnSlot::Warp, rgb: [0.05, 0.07, 0.3] }
        );
        assert_eq!(steps[19], Step::Order { slot: YarnSlot::Weft, text: "2 cream, 1 navy".into() });
        assert_eq!(steps.len(), 20);
    }

    #[test]
    fn the_paint_commands_parse() {
        let text = "paint-start 64 128 16\nwait-paint\npaint-colour 0.1 0.2 0.3\npaint-scope thread\n\
                    paint-at 0.5 0.25\npaint-pick 0 1\npaint-undo\npaint-commit\npaint-verify\nwait-verify\n\
                    paint-leave\npaint-save p.toml\n";
        let steps: Vec<Step> =
            parse_script(text, Path::new("s.txt")).unwrap().into_iter().map(|l| l.step).collect();
        assert_eq!(steps[0], Step::PaintStart { side: 64, spp: 128, verify_spp: Some(16) });
        assert_eq!(steps[2], Step::PaintColour([0.1, 0.2, 0.3]));
        assert_eq!(steps[3], Step::PaintScope(Scope::Thread));
        assert_eq!(steps[4], Step::PaintAt { x: 0.5, y: 0.25 });
        assert_eq!(steps[5], Step::PaintPick { x: 0.0, y: 1.0 });
        assert_eq!(steps[10], Step::PaintLeave);
        assert_eq!(
            steps[11],
            Step::PaintFile { action: PaintFileAction::SavePainting, path: "p.toml".into() }
        );
        assert_eq!(steps.len(), 12);
        for (text, needle) in [
            ("paint-start 4 16\n", "8 <= SIDE"),
            ("paint-colour 2 0 0\n", "0 to 1"),
            ("paint-scope yarn\n", "section, thread or set"),
            ("paint-at 1.5 0\n", "fractions"),
        ] {
            let err = parse_script(text, Path::new("s.txt")).unwrap_err();
            assert!(err.contains(needle), "{err}");
        }
    }

    #[test]
    fn errors_name_the_line() {
        for (text, needle) in [
            ("fit\nspinn 3\n", "s.txt:2: unknown command \"spinn\""),
            ("spin 0\n", "0 < seconds"),
            ("fiber silk beta_r 3\n", "warp or weft"),
            ("fiber warp c_tt 1 1\n", "missing blue"),
            ("mesh sphere\n", "builtin, file or thickness"),
            ("light 0 azimuth\n", "missing azimuth"),
            ("zoom -1\n", "positive"),
            ("fit now\n", "unexpected \"now\""),
            ("export a.png 0x5 4\n", "WIDTHxHEIGHT"),
            ("order warp\n", "missing colour order"),
            ("palette navy selvedge 0 0 0\n", "warp or weft"),
        ] {
            let err = parse_script(text, Path::new("s.txt")).unwrap_err();
            assert!(err.contains(needle), "{err}");
        }
    }

    #[test]
    fn the_viewport_crop_goes_beside_the_window_screenshot() {
        assert_eq!(
            viewport_screenshot_path(Path::new("/tmp/a/shot.png")),
            Path::new("/tmp/a/shot.viewport.png")
        );
    }
}
