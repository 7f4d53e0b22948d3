//! `twill bake --shard I/N` and `twill bake merge`: a bake split across processes or machines
//! (docs/PRECOMPUTATION.md, "Sharded bakes").
//!
//! How it works: a shard builds the scene's bake inputs exactly as `twill bake` does (scene,
//! quality, `--set` overrides), computes its slice of the visibility images and IIRTF cells
//! (`twill_precompute::bake::shard`) and writes a part file that records those three things.
//! `merge` reads the parts, rebuilds the inputs from their common record (the scene path must
//! reach the same file on the merging machine: a shared file system on a cluster), checks the
//! parts against them and writes the bake file, the same bytes a single `twill bake` writes.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use twill_precompute::bake::Cancel;
use twill_precompute::bake::pipeline::write_bake;
use twill_precompute::bake::settings::Quality;
use twill_precompute::bake::shard::{Shard, bake_part, merge_parts, read_part, write_part};
use twill_precompute::scene::SceneFile;

use crate::commands::{StageBar, apply_overrides};

/// What a part records to rebuild its inputs.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
struct Record {
    /// The scene file, absolute; empty for the built-in default scene.
    scene: String,
    quality: String,
    overrides: Vec<String>,
}

/// `twill bake --shard I/N`.
pub fn bake_shard(
    scene: Option<&Path>,
    quality: Quality,
    overrides: &[String],
    shard: &str,
    output: Option<PathBuf>,
) -> Result<()> {
    let shard = Shard::parse(shard)?;
    let scene_path = match scene {
        Some(path) => std::path::absolute(path).with_context(|| format!("{}", path.display()))?,
        None => PathBuf::new(),
    };
    let record = Record {
        scene: scene_path.to_string_lossy().into_owned(),
        quality: quality.name().to_owned(),
        overrides: overrides.to_vec(),
    };
    let file = SceneFile::load_or_default(scene)?;
    let built = file.build()?;
    let settings = apply_overrides(quality.settings(), overrides)?;
    let inputs = built.bake_inputs(settings);
    let stem = scene
        .and_then(Path::file_stem)
        .map_or_else(|| "default".to_owned(), |s| s.to_string_lossy().into_owned());
    let output = output.unwrap_or_else(|| {
        PathBuf::from(format!("{stem}.{}.part{}of{}.twillpart", quality.name(), shard.index, shard.count))
    });
    let started = Instant::now();
    let bar = StageBar::new();
    let part = bake_part(&inputs, shard, &Cancel::new(), &|stage, f| bar.update(stage, f));
    bar.finish();
    let part = part.map_err(|e| anyhow::anyhow!("shard {shard} failed: {e}"))?;
    let text = toml::to_string(&record).context("the part's record serializes")?;
    write_part(&output, &part, &text)?;
    for (e, x) in part.exemplars.iter().enumerate() {
        eprintln!("shard {shard}, exemplar {e}: segments {:?}, IIRTF cells {:?}", x.segments, x.cells);
    }
    eprintln!(
        "shard {shard} of {} ({} quality) in {:.2} s -> {}",
        file.path.display(),
        quality.name(),
        started.elapsed().as_secs_f64(),
        output.display()
    );
    Ok(())
}

/// `twill bake merge PARTS... -o FILE`.
pub fn merge(parts: &[PathBuf], output: &Path) -> Result<()> {
    if parts.is_empty() {
        bail!("no part files given");
    }
    let started = Instant::now();
    let mut read = Vec::with_capacity(parts.len());
    let mut record: Option<(Record, &Path)> = None;
    for path in parts {
        let (part, text) = read_part(path)?;
        let this: Record = toml::from_str(&text)
            .map_err(|e| anyhow::anyhow!("{}: its record does not parse: {}", path.display(), e.message()))?;
        match &record {
            Some((first, first_path)) if *first != this => bail!(
                "{} was made from {:?} ({} quality, --set {:?}), {} from {:?} ({} quality, --set {:?}): parts of one bake only",
                path.display(),
                this.scene,
                this.quality,
                this.overrides,
                first_path.display(),
                first.scene,
                first.quality,
                first.overrides
            ),
            Some(_) => {}
            None => record = Some((this, path)),
        }
        read.push(part);
    }
    let (record, _) = record.context("no part files given")?;
    let quality = Quality::ALL
        .into_iter()
        .find(|q| q.name() == record.quality)
        .with_context(|| format!("the parts name an unknown quality {:?}", record.quality))?;
    let scene = (!record.scene.is_empty()).then(|| PathBuf::from(&record.scene));
    let file = SceneFile::load_or_default(scene.as_deref())
        .with_context(|| "the scene the parts were baked from (it must be readable where they are merged)")?;
    let built = file.build()?;
    let settings = apply_overrides(quality.settings(), &record.overrides)?;
    let inputs = built.bake_inputs(settings);
    let count = read.len();
    let bar = StageBar::new();
    let set =
        merge_parts(&inputs, built.pattern_map(), read, &Cancel::new(), &|stage, f| bar.update(stage, f));
    bar.finish();
    let set = set?;
    write_bake(output, &set)?;
    eprintln!(
        "merged {count} parts of {} ({} quality) in {:.2} s -> {} ({:.1} MB)",
        file.path.display(),
        quality.name(),
        started.elapsed().as_secs_f64(),
        output.display(),
        std::fs::metadata(output).map_or(0.0, |m| m.len() as f64 / 1e6)
    );
    Ok(())
}
