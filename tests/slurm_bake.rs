//! A sharded bake on a real Slurm cluster: this machine becomes a single-node cluster (munged,
//! slurmctld and slurmd on localhost, private configuration, key, sockets, ports and state in a
//! temporary folder), `twill bake --slurm 4` submits a job array of four shards and a dependent
//! merge job, and the bake it writes must be byte for byte the one `twill bake` writes in one
//! process. The daemons are stopped when the test ends, pass or fail.
//!
//! Needs Debian's slurm-wlm and munge (scripts/setup.sh installs them) and root (slurmd runs
//! jobs as their user and must be root to do so). Without them the test fails, naming what is
//! missing: a sharded bake that no test ran would land untested.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use twill_tests::twill_binary;

/// Longest the daemons may take to come up, and the bake to finish.
const START_TIMEOUT: Duration = Duration::from_mins(1);
const BAKE_TIMEOUT: Duration = Duration::from_mins(10);

/// A single-node Slurm cluster on this machine, stopped when dropped.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
}

fn which(name: &str) -> Option<PathBuf> {
    ["/usr/sbin", "/usr/bin", "/sbin", "/bin"].iter().map(|d| Path::new(d).join(name)).find(|p| p.is_file())
}

/// A port nobody listens on now.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).expect("a free port").port()
}

fn run(command: &mut Command, what: &str) -> String {
    let out = command.stdin(Stdio::null()).output().unwrap_or_else(|e| panic!("{what}: {e}"));
    assert!(
        out.status.success(),
        "{what} failed: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

impl Cluster {
    fn start() -> Self {
        for daemon in ["munged", "slurmctld", "slurmd", "sbatch", "scontrol", "sinfo"] {
            assert!(
                which(daemon).is_some(),
                "{daemon} not found: install slurm-wlm and munge (apt-get install slurm-wlm munge, or run scripts/setup.sh)"
            );
        }
        let uid = run(Command::new("id").arg("-u"), "id -u");
        assert_eq!(uid.trim(), "0", "the Slurm test runs slurmd, which must be root to run jobs");
        let dir = tempfile::tempdir().expect("a temporary folder");
        let d = dir.path();
        for sub in ["state", "spool", "munge"] {
            std::fs::create_dir_all(d.join(sub)).unwrap();
        }
        // A key of our own: no dependence on the package's /etc/munge.
        let key = d.join("munge").join("munge.key");
        let mut bytes = vec![0_u8; 1024];
        std::io::Read::read_exact(
            &mut std::fs::File::open("/dev/urandom").expect("/dev/urandom"),
            &mut bytes,
        )
        .expect("random bytes for the munge key");
        std::fs::write(&key, bytes).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt as _;
            std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).unwrap();
            std::fs::set_permissions(d.join("munge"), std::fs::Permissions::from_mode(0o700)).unwrap();
        }
        let host = run(Command::new("hostname").arg("-s"), "hostname -s").trim().to_owned();
        let cpus = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
        let p = |name: &str| d.join(name).display().to_string();
        let conf = d.join("slurm.conf");
        let text = format!(
            "ClusterName=twilltest\nSlurmctldHost={host}\nSlurmUser=root\nSlurmdUser=root\n\
             AuthType=auth/munge\nCredType=cred/munge\nAuthInfo=socket={socket}\n\
             StateSaveLocation={state}\nSlurmdSpoolDir={spool}\n\
             SlurmctldPidFile={ctld_pid}\nSlurmdPidFile={d_pid}\n\
             SlurmctldLogFile={ctld_log}\nSlurmdLogFile={d_log}\n\
             SlurmctldPort={ctld_port}\nSlurmdPort={d_port}\n\
             ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nJobAcctGatherType=jobacct_gather/none\n\
             AccountingStorageType=accounting_storage/none\nJobCompType=jobcomp/none\nMpiDefault=none\n\
             SchedulerType=sched/backfill\nSelectType=select/cons_tres\nSelectTypeParameters=CR_Core\n\
             ReturnToService=2\n\
             NodeName={host} CPUs={cpus} State=UNKNOWN\n\
             PartitionName=twill Nodes={host} Default=YES MaxTime=INFINITE State=UP\n",
            socket = p("munge/munge.socket"),
            state = p("state"),
            spool = p("spool"),
            ctld_pid = p("slurmctld.pid"),
            d_pid = p("slurmd.pid"),
            ctld_log = p("slurmctld.log"),
            d_log = p("slurmd.log"),
            ctld_port = free_port(),
            d_port = free_port(),
        );
        std::fs::write(&conf, text).unwrap();
        let cluster = Self { dir, conf };
        let d = cluster.dir.path();
        run(
            Command::new(which("munged").unwrap())
                .arg(format!("--socket={}", d.join("munge/munge.socket").display()))
                .arg(format!("--pid-file={}", d.join("munge/munged.pid").display()))
                .arg(format!("--log-file={}", d.join("munge/munged.log").display()))
                .arg(format!("--seed-file={}", d.join("munge/seed").display()))
                .arg(format!("--key-file={}", key.display()))
                .arg("--force"),
            "munged",
        );
        run(Command::new(which("slurmctld").unwrap()).arg("-f").arg(&cluster.conf), "slurmctld");
        run(Command::new(which("slurmd").unwrap()).arg("-f").arg(&cluster.conf), "slurmd");
        let started = Instant::now();
        loop {
            let state = cluster.command("sinfo").args(["-h", "-o", "%t"]).output().expect("sinfo");
            if String::from_utf8_lossy(&state.stdout).trim() == "idle" {
                break;
            }
            assert!(started.elapsed() < START_TIMEOUT, "the node did not come up:\n{}", cluster.logs());
            std::thread::sleep(Duration::from_millis(500));
        }
        cluster
    }

    /// `program` with this cluster's configuration.
    fn command(&self, program: &str) -> Command {
        let mut command = Command::new(program);
        command.env("SLURM_CONF", &self.conf).stdin(Stdio::null());
        command
    }

    fn logs(&self) -> String {
        let mut text = String::new();
        for f in ["slurmctld.log", "slurmd.log", "munge/munged.log"] {
            let log = std::fs::read_to_string(self.dir.path().join(f)).unwrap_or_default();
            let _ = write!(text, "--- {f}\n{log}");
        }
        text
    }

    /// The pids of the daemons still running.
    fn running(&self) -> Vec<(String, u32)> {
        ["slurmd.pid", "slurmctld.pid", "munge/munged.pid"]
            .iter()
            .filter_map(|f| {
                let pid: u32 = std::fs::read_to_string(self.dir.path().join(f)).ok()?.trim().parse().ok()?;
                alive(pid).then(|| ((*f).to_owned(), pid))
            })
            .collect()
    }
}

/// Whether process `pid` runs (a zombie, ended but not yet reaped by its parent, does not).
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|stat| stat.rsplit_once(')').map(|(_, rest)| !rest.trim_start().starts_with('Z')))
        .unwrap_or(false)
}

impl Drop for Cluster {
    fn drop(&mut self) {
        for (_, pid) in self.running() {
            let _ = Command::new("kill").arg(pid.to_string()).status();
        }
        let started = Instant::now();
        while !self.running().is_empty() && started.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(200));
        }
        for (_, pid) in self.running() {
            let _ = Command::new("kill").args(["-KILL", &pid.to_string()]).status();
        }
    }
}

#[test]
fn a_four_shard_bake_on_slurm_is_byte_for_byte_the_local_bake() {
    let cluster = Cluster::start();
    let out = cluster.dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let twill = twill_binary();
    let local = out.join("local.twillbake");
    run(
        Command::new(&twill).args(["bake", "--quality", "draft", "--no-cache", "-o"]).arg(&local),
        "twill bake",
    );
    let sharded = out.join("slurm.twillbake");
    let started = Instant::now();
    let mut child = cluster
        .command(twill.to_str().unwrap())
        .args(["bake", "--quality", "draft", "--slurm", "4", "-o"])
        .arg(&sharded)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("twill bake --slurm starts");
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if started.elapsed() > BAKE_TIMEOUT {
            let _ = child.kill();
            panic!("the Slurm bake did not finish in {} s:\n{}", BAKE_TIMEOUT.as_secs(), cluster.logs());
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    eprintln!("--- twill bake --slurm 4 ({:.1} s)\n{stderr}", started.elapsed().as_secs_f64());
    assert!(status.success(), "twill bake --slurm failed:\n{stderr}\n{}", cluster.logs());
    assert!(stderr.contains("4/4 shards done"), "it reports progress from the parts: {stderr}");
    let shards = PathBuf::from(format!("{}.shards", sharded.display()));
    for i in 0..4 {
        assert!(
            shards.join(format!("part{i}.twillpart")).is_file(),
            "part {i} was written by its array task"
        );
    }
    assert!(
        std::fs::read(&sharded).unwrap() == std::fs::read(&local).unwrap(),
        "the merged bake differs from the local one"
    );
    let queue = run(cluster.command("squeue").args(["-h", "-o", "%i %T"]), "squeue");
    assert!(queue.trim().is_empty(), "jobs left in the queue: {queue}");
    let dir = cluster.dir.path().to_owned();
    let pids: Vec<u32> = cluster.running().into_iter().map(|(_, pid)| pid).collect();
    assert_eq!(pids.len(), 3, "munged, slurmctld and slurmd ran");
    drop(cluster);
    for pid in pids {
        assert!(!alive(pid), "daemon {pid} outlived the test");
    }
    assert!(!dir.exists(), "the cluster's folder is removed");
}
