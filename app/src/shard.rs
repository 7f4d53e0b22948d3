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

use crate::commands::{StageBar, apply_overrides, scene_stem};

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
    let output = output.unwrap_or_else(|| {
        let stem = scene_stem(scene);
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

/// How `twill bake --slurm` runs.
pub struct SlurmOptions<'a> {
    pub scene: Option<&'a Path>,
    pub quality: Quality,
    pub overrides: &'a [String],
    pub shards: usize,
    pub partition: Option<&'a str>,
    /// The bake file the merge job writes.
    pub output: PathBuf,
    /// Submit and return, without following the jobs.
    pub no_wait: bool,
}

/// Seconds between two looks at the jobs while following them.
const POLL_SECONDS: u64 = 2;

/// `twill bake --slurm N`: writes a job array of N shards and a merge job that depends on it
/// into `OUTPUT.shards/`, submits both with `sbatch`, and follows them (parts written, job
/// states) until the bake file is written or a job fails.
pub fn bake_slurm(options: &SlurmOptions<'_>) -> Result<()> {
    let n = options.shards;
    if !(1..=twill_precompute::bake::shard::MAX_SHARDS).contains(&n) {
        bail!(
            "--slurm {n}: the number of shards must be in 1..={}",
            twill_precompute::bake::shard::MAX_SHARDS
        );
    }
    // Check the scene and settings here, not in N failed jobs.
    let file = SceneFile::load_or_default(options.scene)?;
    file.build()?;
    apply_overrides(options.quality.settings(), options.overrides)?;
    let exe = std::env::current_exe().context("the path of the twill binary")?;
    let output = std::path::absolute(&options.output).context("the output path")?;
    let dir = PathBuf::from(format!("{}.shards", output.display()));
    std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
    let mut bake_args = vec!["bake".to_owned()];
    if let Some(scene) = options.scene {
        bake_args.push(std::path::absolute(scene)?.to_string_lossy().into_owned());
    }
    bake_args.extend(["--quality".to_owned(), options.quality.name().to_owned()]);
    for o in options.overrides {
        bake_args.extend(["--set".to_owned(), o.clone()]);
    }
    let quoted = |args: &[String]| args.iter().map(|a| shell_quote(a)).collect::<Vec<_>>().join(" ");
    let part = |i: &str| dir.join(format!("part{i}.twillpart")).to_string_lossy().into_owned();
    let partition = options.partition.map(|p| format!("#SBATCH --partition={p}\n")).unwrap_or_default();
    // What both scripts run before twill. glibc keeps freed big blocks in per-thread arenas, so
    // a bake's memory grows with a node's cores; a fixed mmap threshold returns them
    // (docs/PRECOMPUTATION.md, "Memory").
    let preamble = format!("{partition}export MALLOC_MMAP_THRESHOLD_={MMAP_THRESHOLD}\n");
    let shard_script = format!(
        "#!/bin/sh\n#SBATCH --job-name=twill-shard\n#SBATCH --array=0-{last}\n#SBATCH --output={log}\n{preamble}\
         exec {exe} {args} --shard \"$SLURM_ARRAY_TASK_ID/{n}\" -o {part}\n",
        last = n - 1,
        log = shell_quote(&dir.join("shard-%a.log").to_string_lossy()),
        exe = shell_quote(&exe.to_string_lossy()),
        args = quoted(&bake_args),
        part = shell_quote(&part("X")).replace("partX", "part'\"$SLURM_ARRAY_TASK_ID\"'"),
    );
    let parts: Vec<String> = (0..n).map(|i| part(&i.to_string())).collect();
    let merge_script = format!(
        "#!/bin/sh\n#SBATCH --job-name=twill-merge\n#SBATCH --output={log}\n{preamble}exec {exe} bake merge {parts} -o {out}\n",
        log = shell_quote(&dir.join("merge.log").to_string_lossy()),
        exe = shell_quote(&exe.to_string_lossy()),
        parts = quoted(&parts),
        out = shell_quote(&output.to_string_lossy()),
    );
    let (shard_path, merge_path) = (dir.join("shard.sbatch"), dir.join("merge.sbatch"));
    std::fs::write(&shard_path, shard_script).with_context(|| format!("{}", shard_path.display()))?;
    std::fs::write(&merge_path, merge_script).with_context(|| format!("{}", merge_path.display()))?;
    for p in &parts {
        let _ = std::fs::remove_file(p);
    }
    let _ = std::fs::remove_file(&output);
    let array = sbatch(&[shard_path.as_os_str()])?;
    let dependency = format!("--dependency=afterok:{array}");
    let merge = sbatch(&[std::ffi::OsStr::new(&dependency), merge_path.as_os_str()])?;
    eprintln!(
        "submitted shard array {array} ({n} tasks) and merge job {merge}: {} (scripts and logs in {})",
        output.display(),
        dir.display()
    );
    if options.no_wait {
        return Ok(());
    }
    let started = Instant::now();
    let mut reported = usize::MAX;
    loop {
        std::thread::sleep(std::time::Duration::from_secs(POLL_SECONDS));
        let done = parts.iter().filter(|p| Path::new(p).is_file()).count();
        if done != reported {
            eprintln!("{done}/{n} shards done ({:.0} s)", started.elapsed().as_secs_f64());
            reported = done;
        }
        let states = job_states(&array)?;
        if let Some(failed) = states.iter().find(|s| is_failure(s)) {
            bail!("a shard job ended {failed}: see {}", dir.join("shard-*.log").display());
        }
        let merge_state = job_states(&merge)?;
        match merge_state.first().map(String::as_str) {
            Some("COMPLETED") => break,
            Some(state) if is_failure(state) => {
                let log = std::fs::read_to_string(dir.join("merge.log")).unwrap_or_default();
                bail!("the merge job ended {state}:\n{log}");
            }
            _ => {}
        }
    }
    eprintln!(
        "baked {} on Slurm in {:.1} s ({n} shards) -> {} ({:.1} MB)",
        file.path.display(),
        started.elapsed().as_secs_f64(),
        output.display(),
        std::fs::metadata(&output).map_or(0.0, |m| m.len() as f64 / 1e6)
    );
    Ok(())
}

/// The glibc mmap threshold (bytes) the Slurm scripts set: allocations above it are mapped
/// and unmapped on their own instead of kept in the allocator's arenas.
const MMAP_THRESHOLD: usize = 128 * 1024;

/// Submits a batch script; returns the job id.
fn sbatch(args: &[&std::ffi::OsStr]) -> Result<String> {
    let out = std::process::Command::new("sbatch")
        .arg("--parsable")
        .args(args)
        .output()
        .context("running sbatch (is Slurm installed and SLURM_CONF set?)")?;
    if !out.status.success() {
        bail!("sbatch failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let id = text.trim().split(';').next().unwrap_or_default().to_owned();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        bail!("sbatch printed no job id: {text:?}");
    }
    Ok(id)
}

/// The states of every task of job `id` (`scontrol show job`), e.g. `PENDING`, `COMPLETED`.
fn job_states(id: &str) -> Result<Vec<String>> {
    let out = std::process::Command::new("scontrol")
        .args(["show", "job", "-o", id])
        .output()
        .context("running scontrol")?;
    if !out.status.success() {
        bail!("scontrol show job {id} failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|line| {
            line.split_whitespace().find_map(|w| w.strip_prefix("JobState=")).map(str::to_owned)
        })
        .collect())
}

fn is_failure(state: &str) -> bool {
    matches!(
        state,
        "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL" | "OUT_OF_MEMORY" | "BOOT_FAIL" | "DEADLINE"
    )
}

/// `text` quoted for a POSIX shell.
fn shell_quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', "'\\''"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shell_quoting_survives_spaces_and_quotes() {
        assert_eq!(shell_quote("a b"), "'a b'");
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
        assert!(is_failure("FAILED") && !is_failure("COMPLETED") && !is_failure("PENDING"));
    }
}
