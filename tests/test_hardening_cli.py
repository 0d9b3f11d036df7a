"""Hardening of the command line (issue 19): inputs never overwritten, exit codes,
orphan-free campaigns, worker deaths, work estimates, atomic reports, messages.

Processes and signals are bounded in time (every wait has a timeout) and use no
network but the loopback.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from archself.cli import main
from archself.errors import EXIT_CODES, OutputError
from archself.io.files import protect, write_text

from conftest import FIXTURES, ROOT

MINIMAL = FIXTURES / "valid" / "minimal.yaml"
ARCHSELF = [str(Path(sys.executable).with_name("archself"))]


def run(args: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str, str]:
    """``archself ARGS`` in this process, through ``main()`` (its exit-code mapping)."""
    monkeypatch.setattr(sys, "argv", ["archself", *map(str, args)])
    old = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(SystemExit) as info:
            main()
    finally:
        signal.signal(signal.SIGTERM, old)
    cap = capsys.readouterr()
    code = info.value.code
    return (code if isinstance(code, int) else (0 if code is None else 1)), cap.out, cap.err


@pytest.fixture
def arch(tmp_path: Path) -> Path:
    p = tmp_path / "X.yaml"
    p.write_bytes(MINIMAL.read_bytes())
    return p


def one_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "internal error" not in lines[0] and "Traceback" not in err
    return lines[0]


# --------------------------------------------------------------------------- 1. input destroyed
def test_simulate_trace_onto_the_input_is_refused(arch, monkeypatch, capsys) -> None:
    before = arch.read_bytes()
    code, _, err = run(["simulate", arch, "-s", "calm", "--trace", arch], monkeypatch, capsys)
    assert code == 1 and "is the input file X.yaml" in one_line(err)
    assert arch.read_bytes() == before


def test_hard_link_and_symlink_to_the_input_are_refused(arch, monkeypatch, capsys) -> None:
    before = arch.read_bytes()
    (arch.parent / "hard.json").hardlink_to(arch)
    (arch.parent / "soft.json").symlink_to(arch)
    for name in ("hard.json", "soft.json"):
        code, _, err = run(
            ["simulate", arch, "-s", "calm", "--trace", arch.parent / name], monkeypatch, capsys
        )
        assert code == 1 and "refusing to write over it" in one_line(err), name
    assert arch.read_bytes() == before


def test_the_fixed_trace_sibling_is_checked_too(tmp_path, monkeypatch, capsys) -> None:
    src = tmp_path / "run.fixed.json"  # the input is named like the '.fixed' sibling
    src.write_bytes(MINIMAL.read_bytes())
    before = src.read_bytes()
    code, _, err = run(
        ["simulate", src, "-s", "calm", "--compare", "--trace", tmp_path / "run.json"],
        monkeypatch,
        capsys,
    )
    assert code == 1 and "is the input file run.fixed.json" in one_line(err)
    assert src.read_bytes() == before and not (tmp_path / "run.json").exists()


def test_campaign_out_onto_the_input_is_refused_even_with_force(
    arch, monkeypatch, capsys
) -> None:
    before = arch.read_bytes()
    code, _, err = run(
        ["campaign", arch, "-s", "calm", "--seeds", "1", "-o", arch, "--force"], monkeypatch, capsys
    )
    assert code == 1 and "--out is the input file" in one_line(err)
    assert arch.read_bytes() == before


def test_campaign_trace_onto_the_input_is_refused(tmp_path, monkeypatch, capsys) -> None:
    traces = tmp_path / "traces"
    traces.mkdir()
    src = traces / "calm_r0000_fixed.json"  # exactly the name of replicate 0's fixed trace
    src.write_bytes(MINIMAL.read_bytes())
    before = src.read_bytes()
    code, _, err = run(
        ["campaign", src, "-s", "calm", "--seeds", "1", "--traces", traces,
         "-o", tmp_path / "r.parquet"],
        monkeypatch,
        capsys,
    )
    assert code == 1 and "overwrite the input file" in one_line(err)
    assert src.read_bytes() == before


def test_report_into_the_folder_of_its_input_is_refused(arch, monkeypatch, capsys) -> None:
    before = arch.read_bytes()
    for out in (arch.parent, arch.parent.parent):
        code, _, err = run(["report", arch, "-o", out, "--force"], monkeypatch, capsys)
        assert code == 1 and "holds the input file" in one_line(err)
    assert arch.read_bytes() == before


def test_write_over_a_protected_input_is_refused_at_the_write(tmp_path) -> None:
    f = tmp_path / "in.yaml"
    f.write_text("a: 1")
    with protect([f]), pytest.raises(OutputError, match="is the input file"):
        write_text(f, "overwritten")
    assert f.read_text() == "a: 1"
    write_text(f, "free again")  # protection ends with the block
    assert f.read_text() == "free again"


# --------------------------------------------------------------------------- 4. exit codes
def _wrong_inputs(tmp: Path) -> dict[str, Path]:
    """An input of each wrong kind."""
    (tmp / "folder").mkdir(exist_ok=True)
    (tmp / "folder.yaml").mkdir(exist_ok=True)
    (tmp / "empty.yaml").write_text("")
    (tmp / "binary.yaml").write_bytes(b"\x00\xff\xfe" * 100)
    (tmp / "garbage.json").write_text("{not json")
    return {
        "missing": tmp / "missing.yaml",
        "folder": tmp / "folder",
        "device": Path("/dev/zero"),
        "null": Path("/dev/null"),
        "empty": tmp / "empty.yaml",
        "binary": tmp / "binary.yaml",
        "garbage": tmp / "garbage.json",
    }


def _cases(tmp: Path, arch: Path) -> list[list[str]]:
    """Every option of every command with a wrong value of each kind."""
    bad_in = _wrong_inputs(tmp)
    (tmp / "a-file").write_text("x")
    bad_out_file = {
        "no folder": tmp / "no" / "such" / "out.json",
        "unwritable": Path("/proc/archself-test/out.json"),
        "a folder": tmp / "folder",
    }
    bad_out_dir = {"a file": tmp / "a-file", "unwritable": Path("/proc/archself-test/dir")}
    a = str(arch)
    cases: list[list[str]] = []
    for p in bad_in.values():
        cases += [
            ["validate", str(p)],
            ["simulate", str(p), "-s", "calm"],
            ["report", str(p), "-o", str(tmp / "rep")],
            ["campaign", str(p), "-s", "calm", "--seeds", "1", "-o", str(tmp / "c.parquet")],
            ["explain", str(p)],
            ["campaign-report", str(p), "-o", str(tmp / "crep")],
            ["export", str(p), "--to", "graphml"],
            ["info", str(p)],
            ["schema", "--check", str(p)],
        ]
    for p in bad_out_file.values():
        cases += [
            ["simulate", a, "-s", "calm", "--trace", str(p)],
            ["schema", "-o", str(p)],
            ["generate", "10", "-o", str(p)],
            ["export", a, "--to", "graphml", "-o", str(p)],
            ["init", str(p.with_suffix(".yaml"))],
            ["campaign", a, "-s", "calm", "--seeds", "1", "-o", str(p)],
        ]
    for p in bad_out_dir.values():
        cases += [
            ["report", a, "-o", str(p)],
            ["simulate", a, "-s", "calm", "--report", str(p)],
            ["campaign", a, "-s", "calm", "--seeds", "1", "--traces", str(p), "-o",
             str(tmp / "t.parquet")],
            ["docs", str(p)],
        ]
    wrong = ["-1", "abc", "", "1e3", "nan"]  # for options that accept 0
    for v in wrong:
        cases += [
            ["simulate", a, "-s", "calm", "--seed", v],
            ["campaign", a, "-s", "calm", "--seeds", "1", "--root-seed", v, "-o",
             str(tmp / "n.parquet")],
            ["generate", "10", "--seed", v],
            ["generate", "10", "--feedback", v],
            ["calibrate", a, "--seeds", "1", "--root-seed", v],
            ["identify", a, "--seeds", "1", "--root-seed", v],
        ]
    for v in ["0", *wrong]:  # for options that need at least 1 (or 2)
        cases += [
            ["campaign", a, "-s", "calm", "--seeds", v, "-o", str(tmp / "n.parquet")],
            ["campaign", a, "-s", "calm", "--seeds", "1", "--workers", v, "-o",
             str(tmp / "n.parquet")],
            ["generate", v],
            ["generate", "10", "--fan-in", v],
        ]
    cases += [
        ["generate", "100000000"],
        ["simulate", a, "-s", "nope"],
        ["simulate", a, "-s", "calm", "-c", "nope"],
        ["simulate", a, "-s", "calm", "--fixed", "--compare"],
        ["campaign", a, "-s", "nope", "--seeds", "1"],
        ["campaign", a, "-s", "calm", "-s", "calm", "--seeds", "1"],
        ["campaign", a, "-s", "calm", "--seeds", "1", "--mode", "sideways"],
        ["campaign", a, "-s", "calm", "--seeds", "1", "--executor", "cloud"],
        ["campaign", a, "-s", "calm", "--seeds", "1", "--address", "tcp://127.0.0.1:1"],
        ["campaign", a, "-s", "calm", "--seeds", "1", "--executor", "dask", "--address",
         "not a url"],
        ["campaign", a, "-s", "calm", "--seeds", "1", "--resume", "--force"],
        ["campaign", a, "-s", "calm", "--seeds", "1", "--resume", "-o",
         str(bad_in["garbage"])],
        ["campaign", a, "-s", "calm", "--seeds", "1000000000000"],
        ["explain", str(arch)],
        ["campaign-report", str(bad_in["garbage"]), "-o", str(tmp / "crep")],
        ["export", a, "--to", "nope"],
        ["init", str(tmp / "folder")],
        ["init", ""],
        ["init", str(arch)],
        ["generate", "10", "--feedback", str(10**12)],
        ["schema", "--check", str(tmp / "folder")],
        ["docs", str(tmp / "a-file")],
    ]
    for spec in ["runtime.threshold", "runtime.threshold=", "runtime.threshold=a:b:c",
                 "runtime.threshold=0.1:0.9:0", "runtime.threshold=0.1:0.9:-3",
                 "runtime.threshold=0.1:0.9:100000000", "runtime.threshold=nan,1",
                 "runtime.threshold=1e308:1e309:2", "runtime.nope=1,2", "runtime=1,2",
                 "runtime.threshold=-5,5", "x[99999999999999999999].y=1", "[0]=1",
                 "scenarios.calm.duration_s=1e12"]:
        cases.append(["campaign", a, "-s", "calm", "--seeds", "1", "--sweep", spec, "-o",
                      str(tmp / "s.parquet")])
    return cases


def test_every_option_with_a_wrong_value_is_a_user_error(
    tmp_path, arch, monkeypatch, capsys
) -> None:
    failures = []
    cases = _cases(tmp_path, arch)
    for args in cases:
        t0 = time.perf_counter()
        code, _out, err = run(args, monkeypatch, capsys)
        dt = time.perf_counter() - t0
        lines = [ln for ln in err.strip().splitlines() if ln.strip()]
        bad = (
            code not in (1, 2)
            or "internal error" in err
            or "Traceback" in err
            or not lines
            or (code == 1 and args[0] != "validate" and len(lines) != 1)
            or dt > 20
        )
        if bad:
            failures.append(f"{args} -> {code} in {dt:.1f} s: {err.strip()[:300]!r}")
    assert not failures, "\n".join(failures)
    assert len(cases) > 150


def _readonly_folder(tmp: Path) -> Path:
    """A folder this process cannot write into (root writes anywhere: then /proc)."""
    if os.geteuid() == 0:
        return Path("/proc/archself-readonly")
    d = tmp / "ro"
    d.mkdir()
    d.chmod(0o555)
    return d / "traces"


@pytest.mark.parametrize(
    ("case", "code", "fragment"),
    [
        ("root-seed", 2, "--root-seed"),
        ("address", 1, "not a Dask scheduler address"),
        ("traces-readonly", 1, "--traces folder cannot be written"),
        ("generate-huge", 1, "more than the cap of 100,000"),
        ("acceptable-1e308", 1, "runtime.objective.acceptable: expected a number ≤ 1e+09"),
        ("dev-zero", 1, "is a character device"),
    ],
)
def test_audit_user_mistakes_are_not_internal_errors(
    case, code, fragment, tmp_path, arch, monkeypatch, capsys
) -> None:
    big = tmp_path / "big.yaml"
    big.write_text(
        arch.read_text().replace("components: [0, 1]}", "components: [0, 1], acceptable: 1e308}")
    )
    args = {
        "root-seed": ["campaign", arch, "-s", "calm", "--seeds", "1", "--root-seed", "-1"],
        "address": ["campaign", arch, "-s", "calm", "--seeds", "1", "--executor", "dask",
                    "--address", "not a url", "-o", tmp_path / "r.parquet"],
        "traces-readonly": ["campaign", arch, "-s", "calm", "--seeds", "1", "--traces",
                            _readonly_folder(tmp_path), "-o", tmp_path / "r.parquet"],
        "generate-huge": ["generate", "100000000"],
        "acceptable-1e308": ["simulate", big, "-s", "calm"],
        "dev-zero": ["simulate", "/dev/zero", "-s", "calm"],
    }[case]
    got, _, err = run(args, monkeypatch, capsys)
    assert got == code, err
    assert fragment in err and "internal error" not in err
    if code == 1:
        one_line(err)


def test_exit_codes_are_documented() -> None:
    page = (ROOT / "docs" / "hardening.md").read_text(encoding="utf-8")
    for code in EXIT_CODES:
        assert f"| {code} |" in page, code


# --------------------------------------------------------------------------- 6. messages
def test_campaign_report_of_dev_null_says_what_it_is(tmp_path, monkeypatch, capsys) -> None:
    code, _, err = run(["campaign-report", "/dev/null", "-o", tmp_path / "r"], monkeypatch, capsys)
    assert code == 1 and "is a character device" in one_line(err) and "no such file" not in err


def test_a_pool_that_cannot_start_says_so(arch, tmp_path, monkeypatch, capsys) -> None:
    import multiprocessing.forkserver

    def gone(*args, **kwargs):
        raise BrokenPipeError(32, "Broken pipe")  # what a dead forkserver gives

    monkeypatch.setattr(multiprocessing.forkserver, "connect_to_new_process", gone)
    monkeypatch.setattr(multiprocessing.forkserver._forkserver, "connect_to_new_process", gone)
    code, _, err = run(
        ["campaign", arch, "-s", "calm", "--seeds", "1", "--workers", "1", "-o",
         tmp_path / "r.parquet"],
        monkeypatch,
        capsys,
    )
    assert code == 1 and "could not start" in one_line(err), err


def test_numeric_warnings_are_located_and_after_the_output(arch, monkeypatch, capsys) -> None:
    import numpy as np

    import archself.cli.runs as cli

    real = cli._run

    def noisy(*args, **kwargs):
        for _ in range(3):
            np.log(np.zeros(2))  # RuntimeWarning: divide by zero (three times)
        return real(*args, **kwargs)

    monkeypatch.setattr(cli, "_run", noisy)
    code, out, err = run(["simulate", arch, "-s", "calm", "--fixed"], monkeypatch, capsys)
    assert code == 0 and "max error" in out
    assert one_line(err).startswith(f"{arch}: warning: RuntimeWarning: divide by zero")


def test_numeric_warnings_do_not_precede_an_error(arch, monkeypatch, capsys) -> None:
    import numpy as np

    import archself.cli.runs as cli
    from archself.errors import SimulationError

    def noisy(*args, **kwargs):
        np.log(np.zeros(2))
        raise SimulationError(f"{arch}: error: the run failed")

    monkeypatch.setattr(cli, "_run", noisy)
    code, _, err = run(["simulate", arch, "-s", "calm", "--fixed"], monkeypatch, capsys)
    lines = err.strip().splitlines()
    assert code == 1 and lines[0] == f"{arch}: error: the run failed", err


def _catches(pid: int, sig: int) -> bool:
    """Whether process ``pid`` has a handler for ``sig`` (Linux: ``SigCgt`` of its status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return True  # gone or not Linux: do not wait for it
    caught = next((int(line.split()[1], 16) for line in status.splitlines()
                   if line.startswith("SigCgt:")), None)
    return caught is None or bool(caught >> (int(sig) - 1) & 1)


def _signal_after_start(
    args: list[str], sig: int, tmp: Path, marker: str | None = None, delay: float = 2.0
) -> tuple[int, str]:
    """Start ``archself ARGS`` in ``tmp``, send ``sig`` once a file named ``marker*``
    appears (or after ``delay`` s and once the process catches ``sig``: a loaded machine
    may still be importing after ``delay``); the exit code and stderr. Bounded: 60 s."""
    err_path = tmp / f"stderr-{int(sig)}.txt"
    with open(err_path, "w") as err_file:
        proc = subprocess.Popen(ARCHSELF + args, stdout=subprocess.DEVNULL, stderr=err_file,
                                cwd=tmp)
        try:
            t0 = time.monotonic()
            while time.monotonic() - t0 < 60 and proc.poll() is None:
                if (marker is None and time.monotonic() - t0 >= delay
                        and _catches(proc.pid, sig)):
                    break
                if marker is not None and any(p.name.startswith(marker) for p in tmp.iterdir()):
                    break
                time.sleep(0.02)
            proc.send_signal(sig)
            code = proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
    return code, err_path.read_text()


SIGNALS = [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")]


@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS)
def test_a_signal_on_simulate_says_so(sig, code, word, tmp_path) -> None:
    diffdrive = ROOT / "architectures" / "diffdrive.yaml"
    got, err = _signal_after_start(
        ["simulate", str(diffdrive), "-s", "imu_drift", "--compare", "--trace", "t.json"],
        sig, tmp_path, delay=2.0,
    )
    if got == 0:
        pytest.skip("the run finished before the signal")
    assert got == code and err.strip().splitlines()[-1] == word, (got, err)
    # no half trace: a trace is there whole (written atomically, the signal may come between
    # the fixed and the adaptive one) or not at all, and no temporary file is left
    assert all(json.loads(p.read_text())["meta"] for p in tmp_path.glob("*.json"))
    assert not list(tmp_path.glob(".t.*")), "no temporary file"


@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS)
def test_a_signal_on_report_leaves_no_half_report(sig, code, word, tmp_path) -> None:
    diffdrive = ROOT / "architectures" / "diffdrive.yaml"
    old = tmp_path / "rep"
    old.mkdir()
    (old / "index.html").write_text("the old report")
    got, err = _signal_after_start(
        ["report", str(diffdrive), "-o", "rep", "--force"], sig, tmp_path, marker=".rep."
    )
    if got == 0:
        pytest.skip("the report was complete before the signal")
    assert got == code and err.strip().splitlines()[-1] == word, (got, err)
    assert [p.name for p in old.iterdir()] == ["index.html"], "the old report is untouched"
    assert (old / "index.html").read_text() == "the old report"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".rep.")], "temp removed"


# --------------------------------------------------------------------------- 2, 3. campaigns
def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (psutil if installed, else /proc by ppid)."""
    try:
        import psutil

        return [p.pid for p in psutil.Process(pid).children(recursive=True)]
    except ImportError:
        pass
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            kids.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        for k in kids.get(todo.pop(), []):
            out.append(k)
            todo.append(k)
    return out


def _running(pid: int) -> bool:
    """Alive and not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def _start_campaign(tmp: Path, arch: Path, seeds: int, out: str = "r.parquet"):
    err = open(tmp / "campaign.err", "w")  # noqa: SIM115 - closed by the caller's wait
    proc = subprocess.Popen(
        # one run per job (--lanes 1): these tests time signals against runs finishing
        ARCHSELF + ["campaign", str(arch), "-s", "calm", "--seeds", str(seeds), "--workers", "2",
                    "-o", out, "--force", "--lanes", "1"],
        stdout=subprocess.DEVNULL, stderr=err, cwd=tmp,
    )
    # wait until the forkserver has forked both workers (grandchildren of the driver)
    t0 = time.monotonic()
    kids: list[int] = []
    while time.monotonic() - t0 < 60 and proc.poll() is None:
        kids = _descendants(proc.pid)
        if len(kids) >= 4:  # resource tracker, forkserver, 2 workers
            break
        time.sleep(0.05)
    return proc, kids, err


def _workers(pid: int) -> list[int]:
    """The pool workers: the processes two levels below the driver (forkserver's children)."""
    children = set()
    for k in _descendants(pid):
        try:
            ppid = int(Path(f"/proc/{k}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        if ppid != pid:
            children.add(k)
    return sorted(children)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and forkserver")
def test_sigkill_of_the_driver_leaves_no_orphans(tmp_path, arch) -> None:
    proc, kids, err = _start_campaign(tmp_path, arch, seeds=30)
    try:
        assert len(kids) >= 4, kids
        time.sleep(0.5)
        proc.kill()
        t0 = time.monotonic()
        proc.wait(timeout=10)
        while time.monotonic() - t0 < 10 and any(_running(k) for k in kids):
            time.sleep(0.05)
        gone_after = time.monotonic() - t0
        left = [k for k in kids if _running(k)]
    finally:
        err.close()
        for k in kids:
            if _running(k):
                os.kill(k, signal.SIGKILL)
    assert not left, f"still running after {gone_after:.1f} s: {left}"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and forkserver")
def test_sigterm_keeps_the_finished_runs_and_exits_143(tmp_path, arch) -> None:
    from archself.campaign.results import read_results

    # 600 runs: enough that the campaign is still running at its first flush (2 s) even on
    # an idle machine (with 60 it could finish first and the signal came after the end)
    proc, kids, err = _start_campaign(tmp_path, arch, seeds=300)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60 and not (tmp_path / "r.parquet").exists():
            time.sleep(0.05)  # the first flush: some runs are finished
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=30)
        t1 = time.monotonic()
        while time.monotonic() - t1 < 10 and any(_running(k) for k in kids):
            time.sleep(0.05)
        left = [k for k in kids if _running(k)]
    finally:
        err.close()
        for k in kids:
            if _running(k):
                os.kill(k, signal.SIGKILL)
    text = (tmp_path / "campaign.err").read_text()
    assert code == 143, text
    assert text.strip().splitlines()[-1].startswith("terminated: ") and "--resume" in text
    table, _ = read_results(tmp_path / "r.parquet")
    assert 0 < table.num_rows < 600
    assert not left


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and forkserver")
def test_a_killed_worker_is_replaced_and_the_campaign_finishes(tmp_path, arch) -> None:
    from archself.campaign.results import read_results

    # enough runs that the kill lands while work is left: 400 runs of X.yaml (≈ 0.02 s
    # each); the kill comes as soon as the workers run, not after a fixed wait (60 seeds
    # and a 1 s wait let the campaign finish first on an idle machine)
    proc, kids, err = _start_campaign(tmp_path, arch, seeds=200)
    try:
        time.sleep(0.2)
        workers = _workers(proc.pid)
        assert workers, kids
        os.kill(workers[0], signal.SIGKILL)
        code = proc.wait(timeout=120)
    finally:
        err.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = (tmp_path / "campaign.err").read_text()
    assert code == 0, text
    assert "a worker process died" in text and "pool restarted (1/10)" in text
    table, _ = read_results(tmp_path / "r.parquet")
    assert table.num_rows == 400 and all(e is None for e in table.column("error").to_pylist())


def poison_job(job):
    """A run that kills its worker (a crash in C code, the OOM killer) — always."""
    if job.replicate == 1 and job.mode == "fixed":
        os._exit(9)
    from archself.campaign.worker import run_job

    return run_job(job)


def test_a_run_that_always_kills_its_worker_becomes_a_failed_row(tmp_path, arch) -> None:
    from archself.campaign.driver import MAX_ATTEMPTS, plan_campaign, run_campaign

    jobs, meta = plan_campaign(arch, ["calm"], 3)
    notes: list[str] = []
    outcome = run_campaign(jobs, meta, tmp_path / "r.parquet", workers=2, notice=notes.append,
                           job_fn=poison_job)
    assert outcome.rows == 6 and outcome.failed == 1
    assert outcome.errors == [f"calm|1|fixed: worker process died ({MAX_ATTEMPTS + 1} tries)"]
    assert len(notes) == MAX_ATTEMPTS + 1 and "retried one at a time" in notes[0]


# --------------------------------------------------------------------------- 5. size, reports
def _many_configurations(tmp: Path, n: int) -> Path:
    text = MINIMAL.read_text()
    head, conf = text.split("configurations:\n  only:\n    initial: true\n")
    modules, rest = conf.split("\n", 1)
    extra = "".join(f"  c{i}:\n{modules}\n" for i in range(n))
    p = tmp / "many.yaml"
    p.write_text(f"{head}configurations:\n  only:\n    initial: true\n{modules}\n{extra}{rest}")
    return p


def test_report_refuses_too_many_files_before_writing(tmp_path, monkeypatch, capsys) -> None:
    from archself.reports.architecture import MAX_FILES

    big = _many_configurations(tmp_path, MAX_FILES // 6)
    t0 = time.perf_counter()
    code, _, err = run(["report", big, "-o", tmp_path / "rep", "--no-render"], monkeypatch,
                       capsys)
    assert code == 1 and "pass --yes" in one_line(err) and f"cap of {MAX_FILES:,}" in err
    assert time.perf_counter() - t0 < 30
    assert not (tmp_path / "rep").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["many.yaml"], "no temporary folder left"


def test_report_needs_force_and_leaves_no_stale_files(arch, tmp_path, monkeypatch, capsys) -> None:
    out = tmp_path / "rep"
    assert run(["report", arch, "-o", out, "--no-render"], monkeypatch, capsys)[0] == 0
    first = sorted(p.name for p in out.iterdir())
    (out / "stale-from-an-old-report.html").write_text("old")
    code, _, err = run(["report", arch, "-o", out, "--no-render"], monkeypatch, capsys)
    assert code == 1 and "pass --force" in one_line(err)
    assert (out / "stale-from-an-old-report.html").exists()
    assert run(["report", arch, "-o", out, "--no-render", "--force"], monkeypatch, capsys)[0] == 0
    assert sorted(p.name for p in out.iterdir()) == first, "stale file gone"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["X.yaml", "rep"], "no temporary left"
    other = tmp_path / "not-a-report"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    code, _, err = run(["report", arch, "-o", other, "--force"], monkeypatch, capsys)
    assert code == 1 and "not an archself report" in one_line(err)
    assert (other / "notes.txt").read_text() == "mine"


def test_a_failed_report_leaves_the_old_one_whole(arch, tmp_path, monkeypatch, capsys) -> None:
    import archself.reports.architecture as ra

    out = tmp_path / "rep"
    assert run(["report", arch, "-o", out, "--no-render"], monkeypatch, capsys)[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    calls = {"n": 0}
    real = ra.render

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:
            raise OSError(28, "No space left on device", str(out / "x"))
        return real(*args, **kwargs)

    monkeypatch.setattr(ra, "render", failing)
    code, _, err = run(["report", arch, "-o", out, "--no-render", "--force"], monkeypatch, capsys)
    assert code == 1 and "No space left" in one_line(err)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["X.yaml", "rep"]


def test_huge_campaigns_are_refused_at_once(arch, tmp_path, monkeypatch, capsys) -> None:
    for args, fragment in (
        (["--seeds", "1000000000000"], "memory"),
        (["--seeds", "1", "--sweep", "runtime.threshold=0.1:0.9:100000000"], "10,000 values"),
        (["--seeds", "100000"], "pass --yes"),
        (["--seeds", "1", "--sweep", "scenarios.calm.duration_s=1e12"], "pass --yes"),
    ):
        t0 = time.perf_counter()
        code, _, err = run(["campaign", arch, "-s", "calm", *args, "-o", tmp_path / "r.parquet"],
                           monkeypatch, capsys)
        assert code == 1 and fragment in one_line(err), (args, err)
        assert time.perf_counter() - t0 < 10, args
    assert not (tmp_path / "r.parquet").exists()


def test_campaign_estimate_text() -> None:
    from archself.campaign.driver import CampaignEstimate

    est = CampaignEstimate(runs=1200, steps=1200 * 8000, memory_bytes=1200 * 2048)
    assert est.text() == "1,200 runs × 8,000 steps = 9.6e+06 steps, ~2 MB"


def test_a_huge_simulation_is_refused_with_its_estimate(arch, monkeypatch, capsys) -> None:
    long = arch.with_name("long.yaml")
    # 10^6 s at 0.05 s: 2·10^7 steps, valid (under check's 10^8 per run) but past simulate's cap
    long.write_text(arch.read_text().replace("calm: {duration_s: 20}", "calm: {duration_s: 1e6}"))
    code, _, err = run(["simulate", long, "-s", "calm"], monkeypatch, capsys)
    assert code == 1 and "20,000,000 steps" in one_line(err) and "--yes" in err


def test_nan_inside_a_list_is_one_located_line(tmp_path, monkeypatch, capsys) -> None:
    bad = tmp_path / "nan.yaml"
    bad.write_text(MINIMAL.read_text().replace("[5, 1]", "[5, .nan]"))
    code, _, err = run(["validate", bad], monkeypatch, capsys)
    assert code == 1
    assert "expected a finite number, got .nan" in one_line(err)


def test_a_run_report_never_lands_on_the_users_own_files(arch, tmp_path, monkeypatch,
                                                         capsys) -> None:
    """simulate --report, report --trace and calibrate --report write fixed names
    (index.html, summary.json, ...): a folder of other files is refused before any run,
    an earlier report of the same kind is replaced, report --trace --force goes ahead."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "index.html").write_text("my own page")
    code, _, err = run(["simulate", arch, "-s", "calm", "--report", mine], monkeypatch, capsys)
    assert code == 1 and "holds other files and no earlier report" in one_line(err)
    assert (mine / "index.html").read_text() == "my own page"
    trace, rep = tmp_path / "t.json", tmp_path / "rep"
    code, _, err = run(["simulate", arch, "-s", "calm", "--trace", trace, "--report", rep],
                       monkeypatch, capsys)
    assert code == 0, err
    code, _, err = run(["simulate", arch, "-s", "calm", "--report", rep], monkeypatch, capsys)
    assert code == 0, err  # an earlier run report is replaced
    code, _, err = run(["report", "--trace", trace, "-o", mine], monkeypatch, capsys)
    assert code == 1 and "holds other files" in one_line(err)
    assert (mine / "index.html").read_text() == "my own page"
    code, _, err = run(["report", "--trace", trace, "-o", mine, "--force"], monkeypatch, capsys)
    assert code == 0, err
    code, _, err = run(["calibrate", arch, "--seeds", "1", "--report", tmp_path / "rep"],
                       monkeypatch, capsys)
    assert code == 1 and "no earlier report (calibration.json)" in one_line(err)


def test_schema_export_generate_never_write_over_an_architecture_file(
    arch, tmp_path, monkeypatch, capsys
) -> None:
    """``-o`` pointed at the user's architecture file by mistake: refused, file intact.
    An earlier output of the command (a schema, a generated file) is written over."""
    mine = tmp_path / "mine.yaml"
    mine.write_text(arch.read_text())
    before = mine.read_bytes()
    for args in (["schema", "-o", mine], ["generate", "5", "-o", mine],
                 ["export", arch, "--to", "graphml", "-o", mine]):
        code, _, err = run(args, monkeypatch, capsys)
        assert code == 1 and "is an architecture file; refusing" in one_line(err), args
        assert mine.read_bytes() == before
    gen, schema = tmp_path / "g.yaml", tmp_path / "s.json"
    for args in (["generate", "5", "-o", gen], ["generate", "6", "-o", gen],
                 ["schema", "-o", schema], ["schema", "-o", schema]):
        code, _, err = run(args, monkeypatch, capsys)
        assert code == 0, err


# --------------------------------------------------------------------------- issue 39: outputs
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="flock, SIGSTOP")
def test_a_second_campaign_into_one_out_is_refused_naming_the_holder(tmp_path, arch) -> None:
    """Two campaigns into one -o: both exited 0 and the file kept the second's rows.
    Now the second (even with --force) is refused in one line naming the first."""
    from archself.campaign.results import read_results

    first = subprocess.Popen(
        ARCHSELF + ["campaign", str(arch), "-s", "calm", "--seeds", "6", "--workers", "1",
                    "-o", "r.parquet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
    )
    lock = tmp_path / "r.parquet.lock"
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60 and first.poll() is None and not (
                lock.exists() and lock.read_text().startswith("pid")):
            time.sleep(0.02)
        assert first.poll() is None, "the first campaign ended before the second started"
        first.send_signal(signal.SIGSTOP)  # holds its lock while the second tries
        try:
            second = subprocess.run(
                ARCHSELF + ["campaign", str(arch), "-s", "calm", "--seeds", "3", "-o",
                            "r.parquet", "--force"],
                capture_output=True, text=True, cwd=tmp_path, timeout=120,
            )
        finally:
            first.send_signal(signal.SIGCONT)
        _, first_err = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert second.returncode == 1, second.stderr
    line = second.stderr.strip()
    assert "\n" not in line
    assert line.startswith(f"r.parquet: error: is being written by pid {first.pid}: "
                           f"archself campaign {arch} -s calm --seeds 6")
    assert first.returncode == 0, first_err
    table, _ = read_results(tmp_path / "r.parquet")
    assert table.num_rows == 12  # the first's rows, all of them
    assert len(set(table.column("seed").to_pylist())) == 6
    assert not lock.exists()  # removed after


def test_output_locks_are_released_and_shared_within_a_process(tmp_path) -> None:
    from archself.io.files import lock_path

    out, folder = tmp_path / "t.json", tmp_path / "rep"
    with protect([], [out, folder, None, "-", "/dev/null"]):
        assert (tmp_path / "t.json.lock").read_text().startswith(f"pid {os.getpid()}: ")
        assert (tmp_path / "rep.lock").exists()
        with protect([], [out]):  # this process holds it already: no self-deadlock
            write_text(out, "x")
        assert (tmp_path / "t.json.lock").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.json"]
    assert lock_path(tmp_path / "missing" / "x") is None  # nothing can be written there


def test_a_failed_report_leaves_no_empty_folder(arch, tmp_path, monkeypatch, capsys) -> None:
    """simulate --report into a full disk left an empty folder behind."""
    import archself.reports.run_report as run_report

    def full(path, data):
        raise OutputError(f"{path}: cannot write: No space left on device")

    monkeypatch.setattr(run_report, "write_text", full)
    target = tmp_path / "new" / "rep"
    code, _, err = run(["simulate", arch, "-s", "calm", "--report", target], monkeypatch, capsys)
    assert code == 1 and "No space left on device" in err
    assert not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["X.yaml"]
