"""A single-node Slurm cluster in a temporary folder, from Debian's packages, for tests.

`LocalSlurm` starts MariaDB, munged, slurmdbd, slurmctld and slurmd itself (no systemd, no
/etc edits): its own munge key and socket, loopback ports, configs written here, state and logs
under the folder. Every daemon runs in the foreground of a process this module started; `stop()`
cancels the cluster's jobs first (job processes outlive a dead slurmd), then ends exactly those
processes by their recorded PIDs. Use it as a context manager so that happens on failure too.

Slurm's clients find the config through SLURM_CONF, which the executor plugin's job step strips
before its inner `srun`: `bin/` holds wrappers for every client (sbatch, srun, sacct, ...) that
set it, and `env()` puts them first on PATH (sbatch hands PATH on to the jobs).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

DAEMONS = ("mariadbd", "munged", "mungekey", "slurmdbd", "slurmctld", "slurmd")
CLIENTS = ("sbatch", "srun", "sacct", "sacctmgr", "squeue", "scontrol", "scancel", "sinfo", "sshare")
PACKAGES = "munge slurmctld slurmd slurm-client slurmdbd mariadb-server"


def missing_binaries() -> list[str]:
    return [name for name in (*DAEMONS, *CLIENTS) if not _which(name)]


def _which(name: str) -> str | None:
    # The daemons live in /usr/sbin, which an unprivileged PATH may lack.
    return shutil.which(name) or shutil.which(name, path="/usr/sbin:/usr/bin:/sbin:/bin")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _node_line(host: str) -> str:
    """The node as `slurmd -C` sees it, on loopback, with a little less memory than it has (a node
    that reports less than slurm.conf says is drained)."""
    out = subprocess.run([_which("slurmd"), "-C"], capture_output=True, text=True, check=True).stdout
    line = out.splitlines()[0]
    mem = int(re.search(r"RealMemory=(\d+)", line).group(1))
    line = re.sub(r"RealMemory=\d+", f"RealMemory={int(mem * 0.9)}", line)
    line = re.sub(r"NodeName=\S+", f"NodeName={host}", line)
    return f"{line} NodeAddr=127.0.0.1 State=UNKNOWN"


@dataclass
class LocalSlurm:
    root: Path
    cluster: str = "r2stest"
    partition: str = "r2s"
    account: str = "r2slab"
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)

    def __post_init__(self):
        self.root = Path(self.root)
        self.host = socket.gethostname().split(".")[0]
        self.conf = self.root / "etc" / "slurm.conf"
        self.bin = self.root / "bin"
        self.logs = self.root / "log"
        self.munge_socket = self.root / "munge-socket" / "munge.socket"
        self.db_port, self.dbd_port, self.ctld_port, self.slurmd_port = (_free_port() for _ in range(4))

    # -- lifecycle ---------------------------------------------------------------------------
    def __enter__(self) -> LocalSlurm:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        for d in ("etc", "log", "state", "spool", "munge-key", "munge-socket", "munge", "db", "bin"):
            (self.root / d).mkdir(parents=True, exist_ok=True)
        os.chmod(self.root / "munge-key", 0o700)
        os.chmod(self.root / "munge-socket", 0o755)
        self._write_wrappers()
        self._start_mariadb()
        self._start_munge()
        self._write_configs()
        self._start("slurmdbd", [_which("slurmdbd"), "-D"], ready=lambda: self._port_open(self.dbd_port))
        # The cluster and its account must be known to the database before slurmctld registers.
        self.sacctmgr("add", "cluster", self.cluster)
        self.sacctmgr("add", "account", self.account, f"cluster={self.cluster}", "description=tests", "organization=tests")
        self.sacctmgr("add", "user", os.environ.get("USER") or "root", f"account={self.account}", f"cluster={self.cluster}")
        self._start("slurmctld", [_which("slurmctld"), "-D", "-i", "-f", str(self.conf)],
                    ready=lambda: self._port_open(self.ctld_port))
        self._start("slurmd", [_which("slurmd"), "-D", "-f", str(self.conf)], ready=self._node_idle, timeout_s=60)

    def stop(self) -> None:
        """Cancel every job of this cluster, then end the daemons this object started (newest
        first), each by its PID."""
        if "slurmctld" in self.procs and self.procs["slurmctld"].poll() is None:
            subprocess.run([self.bin / "scancel", "--full", f"--partition={self.partition}"],
                           env=self.env(), capture_output=True, timeout=30)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and self.active_jobs():
                time.sleep(0.5)
        for name in reversed(list(self.procs)):
            proc = self.procs.pop(name)
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout=30)

    # -- clients -----------------------------------------------------------------------------
    def env(self, base: dict | None = None) -> dict:
        env = dict(os.environ if base is None else base)
        env["PATH"] = f"{self.bin}{os.pathsep}{env.get('PATH', '')}"
        env["SLURM_CONF"] = str(self.conf)
        return env

    def run(self, tool: str, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        proc = subprocess.run([str(self.bin / tool), *args], env=self.env(), capture_output=True, text=True, timeout=60)
        if check and proc.returncode != 0:
            raise RuntimeError(f"{tool} {' '.join(args)} failed: {proc.stderr.strip()}")
        return proc

    def sacctmgr(self, *args: str) -> None:
        self.run("sacctmgr", "-i", *args)

    def active_jobs(self) -> list[str]:
        proc = self.run("squeue", "-h", "-o", "%i", check=False)
        return proc.stdout.split() if proc.returncode == 0 else []

    def accounting(self, *fields: str) -> list[dict[str, str]]:
        """Every job (not its steps) Slurm's accounting recorded, as {field: value}. The job's
        own line, not `sacct -X`'s allocation line: only the former sums its steps' TotalCPU."""
        out = self.run("sacct", "-a", "-n", "-P", "-S", "2000-01-01", "-o", ",".join(("JobID", *fields))).stdout
        rows = [line.split("|") for line in out.splitlines() if line.strip()]
        return [dict(zip(fields, row[1:])) for row in rows if "." not in row[0]]

    # -- daemons -----------------------------------------------------------------------------
    def _start(self, name: str, cmd: list, ready, timeout_s: float = 30, env: dict | None = None) -> None:
        log = open(self.logs / f"{name}.out", "w")
        self.procs[name] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env or self.env(),
                                            start_new_session=True)
        log.close()
        deadline = time.monotonic() + timeout_s
        while not ready():
            if self.procs[name].poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"{name} did not come up:\n{self._log_tail(name)}")
            time.sleep(0.2)

    def _log_tail(self, name: str) -> str:
        texts = [p.read_text(errors="replace")[-3000:] for p in sorted(self.logs.glob(f"{name}*")) if p.is_file()]
        return "\n".join(texts)

    @staticmethod
    def _port_open(port: int) -> bool:
        with socket.socket() as s:
            s.settimeout(0.2)
            return s.connect_ex(("127.0.0.1", port)) == 0

    def _node_idle(self) -> bool:
        proc = self.run("sinfo", "-h", "-N", "-o", "%t", check=False)
        return proc.returncode == 0 and proc.stdout.strip() in {"idle", "mix", "alloc"}

    def _start_mariadb(self) -> None:
        data = self.root / "db"
        subprocess.run([_which("mariadb-install-db"), "--no-defaults", f"--datadir={data}", "--user=root",
                        "--auth-root-authentication-method=normal", "--skip-test-db"],
                       capture_output=True, check=True, timeout=120)
        # No grant tables: the only client is this cluster's slurmdbd, on loopback.
        self._start("mariadbd", [_which("mariadbd"), "--no-defaults", f"--datadir={data}", "--user=root",
                                 f"--socket={self.root / 'db.sock'}", f"--port={self.db_port}",
                                 "--bind-address=127.0.0.1", f"--pid-file={self.root / 'db.pid'}",
                                 "--skip-grant-tables", f"--log-error={self.logs / 'mariadbd.log'}"],
                    ready=lambda: self._port_open(self.db_port), timeout_s=60)

    def _start_munge(self) -> None:
        key = self.root / "munge-key" / "munge.key"
        subprocess.run([_which("mungekey"), "--create", f"--keyfile={key}"], capture_output=True, check=True)
        os.chmod(key, 0o600)
        self._start("munged", [_which("munged"), "-F", f"--key-file={key}", f"--socket={self.munge_socket}",
                               f"--pid-file={self.root / 'munge' / 'munged.pid'}",
                               f"--seed-file={self.root / 'munge' / 'munged.seed'}",
                               f"--log-file={self.logs / 'munged.log'}", "--origin=127.0.0.1", "--force"],
                    ready=self.munge_socket.exists)

    def _write_wrappers(self) -> None:
        for tool in CLIENTS:
            path = self.bin / tool
            path.write_text(f'#!/bin/sh\nSLURM_CONF="{self.conf}" exec "{_which(tool)}" "$@"\n')
            path.chmod(0o755)

    def _write_configs(self) -> None:
        r = self.root
        self.conf.write_text("\n".join([
            f"ClusterName={self.cluster}",
            f"SlurmctldHost={self.host}(127.0.0.1)",
            f"SlurmctldPort={self.ctld_port}",
            f"SlurmdPort={self.slurmd_port}",
            "SlurmUser=root",
            "SlurmdUser=root",
            "AuthType=auth/munge",
            f"AuthInfo=socket={self.munge_socket}",
            "CredType=cred/munge",
            "MpiDefault=none",
            # No cgroups here: CPUs and memory are scheduled, not confined.
            "ProctrackType=proctrack/linuxproc",
            "TaskPlugin=task/none",
            "SelectType=select/cons_tres",
            "SelectTypeParameters=CR_CPU_Memory",
            "SchedulerType=sched/backfill",
            "ReturnToService=2",
            f"StateSaveLocation={r / 'state'}",
            f"SlurmdSpoolDir={r / 'spool'}",
            f"SlurmctldPidFile={r / 'slurmctld.pid'}",
            f"SlurmdPidFile={r / 'slurmd.pid'}",
            f"SlurmctldLogFile={self.logs / 'slurmctld.log'}",
            f"SlurmdLogFile={self.logs / 'slurmd.log'}",
            "SlurmctldDebug=info",
            "SlurmdDebug=info",
            "MailProg=/bin/true",
            "MinJobAge=300",
            "KillWait=5",
            "InactiveLimit=0",
            # Accounting through slurmdbd: sacct answers, accounts are enforced, and every job's
            # CPU time and peak memory are sampled each second.
            "AccountingStorageType=accounting_storage/slurmdbd",
            "AccountingStorageHost=127.0.0.1",
            f"AccountingStoragePort={self.dbd_port}",
            f"AccountingStoragePass={self.munge_socket}",
            "AccountingStorageEnforce=associations",
            "JobAcctGatherType=jobacct_gather/linux",
            "JobAcctGatherFrequency=task=1",
            "JobCompType=jobcomp/none",
            "AccountingStoreFlags=job_comment",  # the executor plugin names rule and wildcards there
            _node_line(self.host),
            f"PartitionName={self.partition} Nodes=ALL Default=YES MaxTime=INFINITE State=UP",
            "",
        ]))
        dbd = self.conf.with_name("slurmdbd.conf")
        dbd.write_text("\n".join([
            "AuthType=auth/munge",
            f"AuthInfo=socket={self.munge_socket}",
            "DbdHost=localhost",
            "DbdAddr=127.0.0.1",
            f"DbdPort={self.dbd_port}",
            "SlurmUser=root",
            f"PidFile={r / 'slurmdbd.pid'}",
            f"LogFile={self.logs / 'slurmdbd.log'}",
            "StorageType=accounting_storage/mysql",
            "StorageHost=127.0.0.1",
            f"StoragePort={self.db_port}",
            "StorageUser=root",
            "StorageLoc=slurm_acct_db",
            "",
        ]))
        dbd.chmod(0o600)
