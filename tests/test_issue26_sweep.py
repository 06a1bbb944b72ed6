"""Issue 26, sweeps: a full disk during an attempt (items 6, Deliver 4), two sweeps into one folder
(item 7, Deliver 5) and the progress counter (item 10).

The sweeps here play a scripted agent on MuJoCo that looks through the head camera until its budget
of tool calls ends: each attempt stays in flight for a few seconds and writes an image per call, so
the tests can catch it there (no duration is asserted)."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest
from test_sweep import CAB, end_group

from cab_core.sweep.attempt_state import check_attempt, infrastructure_failures, log_infrastructure_failure
from cab_core.sweep.manifest import MANIFEST, progress_line

LOOKING = [{"tool": "capture_head", "args": {}}] * 60 + [
    {"tool": "done", "args": {"report": "looked", "success_claim": False}}]


def looking_script(where: Path) -> Path:
    p = where / "look.jsonl"
    p.write_text("".join(json.dumps(item) + "\n" for item in LOOKING))
    return p


def sweep_cmd(sweep_dir: Path, script: Path, attempts=(1, 2, 3, 4), workers: int = 2, *extra: str) -> list[str]:
    return [CAB, "-m", "task=beat_block_hammer", "model=scripted", f"model.script={script}", "sim=mujoco",
            f"attempt={','.join(map(str, attempts))}", "record.video=false", f"hydra.sweep.dir={sweep_dir}",
            f"hydra.launcher.n_jobs={workers}", *extra]


def attempt_dir(sweep_dir: Path, a: int) -> Path:
    return sweep_dir / "beat_block_hammer" / "scripted" / "mujoco" / "seed-0" / f"attempt-{a}"


def wait_in_flight(proc: subprocess.Popen, sweep_dir: Path, attempts) -> None:
    """Until one attempt of the sweep ``proc`` runs is recording (its event log exists)."""
    while not any((attempt_dir(sweep_dir, a) / "events.jsonl").exists() for a in attempts):
        assert proc.poll() is None, f"the sweep ended before an attempt was seen in flight: {proc.stderr.read()}"
        time.sleep(0.1)


def own_lines(stderr: str) -> list[str]:
    """stderr without Hydra's launcher log lines."""
    return [line for line in stderr.splitlines() if "[HYDRA]" not in line]


def counters(stderr: str) -> list[int]:
    return [int(m.group(1)) for m in re.finditer(r"^cab sweep \[(\d+)/\d+\]", stderr, re.M)]


# -- item 10: the progress counter -------------------------------------------------------------------


def _fake_sweep(root: Path, n_jobs: int) -> tuple[Path, int]:
    """A sweep folder of ``n_jobs`` jobs whose session started 10 s ago (its manifest only), and a time
    5 s ago, in nanoseconds, from which the tests date the results they write."""
    t0 = time.time()
    root.mkdir()
    (root / MANIFEST).write_text(json.dumps({"n_jobs": n_jobs, "sessions": [{"started": t0 - 10}]}))
    return root, int((t0 - 5) * 1e9)


def _result(d: Path, ns: int, infra: bool = False) -> Path:
    d.mkdir(parents=True)
    p = d / "result.json"
    p.write_text(json.dumps({"infrastructure": {"failed": infra, "failures": []}}))
    os.utime(p, ns=(ns, ns))
    return p


def test_jobs_finishing_together_each_get_their_own_count(tmp_path):
    """Two jobs whose results are both written before either prints its line: the counts were
    both the number of complete attempts then ([2/3] twice, never [1/3]); each is its own rank."""
    sweep, base = _fake_sweep(tmp_path / "sw", 3)
    a = _result(sweep / "a", base + 2_000)
    b = _result(sweep / "b", base + 1_000)
    assert progress_line(sweep, "a", "done", a).startswith("cab sweep [2/3] a: done | ")
    assert progress_line(sweep, "b", "done", b).startswith("cab sweep [1/3] b: done | ")
    c = _result(sweep / "c", base + 2_000)  # the same time as a: the path decides, for every job alike
    assert progress_line(sweep, "c", "done", c).startswith("cab sweep [3/3] c: done | ")
    assert progress_line(sweep, "a", "done", a).startswith("cab sweep [2/3] a: done | ")
    # a failed attempt counts no place of its own: the attempts complete so far
    bad = _result(sweep / "d", base + 3_000, infra=True)
    assert progress_line(sweep, "d", "INFRASTRUCTURE FAILURE", bad).startswith("cab sweep [3/3] d: ")


def test_a_result_written_again_after_the_other_job_counted_keeps_its_place(tmp_path):
    """``result.json`` is written twice (the verdict, then again once the video is closed): job a's
    first write, job b's result and count, then a's second write and count. Ordered by modification
    time, both jobs printed [2/2] (seen in CI); a keeps the first place b saw it in."""
    sweep, base = _fake_sweep(tmp_path / "sw", 2)
    a = _result(sweep / "a", base + 1_000)
    b = _result(sweep / "b", base + 2_000)
    assert progress_line(sweep, "b", "done", b).startswith("cab sweep [2/2] b: done | ")
    os.utime(a, ns=(base + 3_000, base + 3_000))  # a's second write
    assert progress_line(sweep, "a", "done", a).startswith("cab sweep [1/2] a: done | ")
    assert (sweep / "progress.order").read_text() == "a/result.json\nb/result.json\n"
    # an attempt set aside after it was counted gives up its place
    os.replace(sweep / "a", tmp_path / "aside")
    assert progress_line(sweep, "b", "done", b).startswith("cab sweep [1/2] b: done | ")


# -- item 6: a full disk during an attempt --------------------------------------------------------


def test_failures_whose_entries_a_full_disk_kept_out_are_known_from_their_folders(tmp_path):
    d = tmp_path / "a"
    for name in ("01-crash", "02-hang", "03-interrupted", "04-infrastructure"):
        (d / "set_aside" / name).mkdir(parents=True)
    logged = {"kind": "crash", "detail": "attempt process exit status 1", "try_no": 1, "at": 1.0,
              "records": "set_aside/01-crash"}
    (d / "infrastructure.jsonl").write_text(json.dumps(logged) + '\n{"kind": "ha')  # torn by the full disk
    fails = infrastructure_failures(d)
    assert [f["records"] for f in fails] == ["set_aside/01-crash", "set_aside/02-hang"]
    assert fails[0] == logged
    assert fails[1]["kind"] == "hang" and "could not be written" in fails[1]["detail"]
    # the next entry is not glued to the torn line
    log_infrastructure_failure(d, {**logged, "kind": "hang", "at": 2.0, "records": "set_aside/02-hang"})
    assert [f["kind"] for f in infrastructure_failures(d)] == ["crash", "hang"]
    assert (d / "infrastructure.jsonl").read_text().splitlines()[-1].startswith('{"kind": "hang"')


FULL_DISK = r"""
set -u
mount -t tmpfs -o size=16m tmpfs "$DISK" || exit 97
"$@" 2> "$OUT/first.err" & pid=$!
while [ ! -f "$ATTEMPT/events.jsonl" ] && kill -0 $pid 2>/dev/null; do sleep 0.1; done
head -c 64m /dev/zero > "$DISK/filler" 2>/dev/null
wait $pid; echo $? > "$OUT/first.rc"
cp -a "$DISK/sw" "$OUT/full"
rm "$DISK/filler"
"$@" 2> "$OUT/second.err"; echo $? > "$OUT/second.rc"
cp -a "$DISK/sw" "$OUT/resumed"
"""


def _private_mount_namespace(where: Path) -> list[str] | None:
    """A command prefix that runs a program in a mount namespace of its own, where it may mount a
    tmpfs (as root, or in a user namespace where the kernel allows them); None when neither works."""
    unshare = shutil.which("unshare")
    if unshare is None:
        return None
    for prefix in ([unshare, "-m", "--propagation", "private"], [unshare, "-Urm", "--propagation", "private"]):
        try:
            r = subprocess.run([*prefix, "mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(where)],
                               capture_output=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if r.returncode == 0:
            return prefix
    return None


def _sweep_filling_its_disk(tmp_path: Path, attempts) -> tuple[Path, Path]:
    """Runs FULL_DISK: a one-worker sweep of ``attempts`` on a small tmpfs that fills up while
    attempt 1 records, then again once there is space; the sweep folder (as the runs named it)
    and the folder of what each run left (first/second .err and .rc, full/, resumed/)."""
    disk, out = tmp_path / "disk", tmp_path / "out"
    disk.mkdir()
    out.mkdir()
    ns = _private_mount_namespace(disk)
    if ns is None:
        pytest.skip("no mount namespace to mount a small tmpfs in (needs root or user namespaces)")
    sweep = disk / "sw"
    env = {**os.environ, "DISK": str(disk), "OUT": str(out), "ATTEMPT": str(attempt_dir(sweep, 1))}
    cmd = sweep_cmd(sweep, looking_script(tmp_path), attempts, 1)
    r = subprocess.run([*ns, "bash", "-c", FULL_DISK, "full-disk", *cmd], env=env, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return sweep, out


@pytest.mark.sim
def test_full_disk_during_an_attempt_is_one_line_and_the_resumed_record_lists_the_try(tmp_path):
    """A sweep whose disk fills up while its attempt runs: the attempt's process fails, the
    supervisor can still set its records aside but cannot write its note; one line says what was
    not written and the sweep ends with its resume line. Run again once there is space, the attempt
    completes and its record lists the try that was set aside."""
    sweep, out = _sweep_filling_its_disk(tmp_path, (1,))
    first = (out / "first.err").read_text()
    assert (out / "first.rc").read_text().strip() == "4", first[-3000:]  # incomplete: exit 4 (issue 28)
    assert "Traceback" not in first
    lines = own_lines(first)
    assert len(lines) == 2, lines
    assert lines[0].startswith("cab sweep [0/1] beat_block_hammer/scripted/mujoco/seed-0/attempt-1: INFRASTRUCTURE "
                               "FAILURE (")
    assert "; NOT WRITTEN (No space left on device): infrastructure.jsonl (try 1: " in lines[0]
    assert lines[0].endswith("run the same command again to resume | ETA ?")
    assert lines[1].startswith(f"cab sweep: 0/1 attempts complete, 0 given up on for infrastructure failures (not "
                               f"scored), 1 missing; {sweep}; run the same command to resume: cab ")
    full = attempt_dir(out / "full", 1)
    [aside] = [p.name for p in (full / "set_aside").iterdir()]
    assert not (full / "result.json").exists() and not list(full.glob(".*tmp*"))
    assert (full / "infrastructure.jsonl").read_text() == ""  # the note the full disk refused

    second = (out / "second.err").read_text()
    assert (out / "second.rc").read_text().strip() == "0", second[-3000:]
    assert own_lines(second)[-1] == f"cab sweep: 1/1 attempts complete; {sweep}"
    done = attempt_dir(out / "resumed", 1)
    assert check_attempt(done, {"task": "beat_block_hammer", "attempt": 1, "model": "scripted"}, "cli.log").state \
        == "complete"
    res = json.loads((done / "result.json").read_text())
    assert res["infrastructure"]["failed"] is False
    assert [f["records"] for f in res["infrastructure"]["failures"]] == [f"set_aside/{aside}"]
    assert res["infrastructure"]["failures"][0]["kind"] == aside.split("-", 1)[1]
    assert sorted(p.name for p in (done / "set_aside").iterdir()) == [aside]


# -- item 7: two sweeps into one folder -----------------------------------------------------------


@pytest.mark.sim
def test_a_second_sweep_into_a_running_sweeps_folder_is_refused(tmp_path):
    sweep = tmp_path / "sw"
    cmd = sweep_cmd(sweep, looking_script(tmp_path))
    first = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             start_new_session=True)
    try:
        wait_in_flight(first, sweep, (1, 2, 3, 4))
        os.killpg(first.pid, signal.SIGSTOP)  # it runs on, holding its folder, until the checks are done
        manifest = (sweep / MANIFEST).read_bytes()
        for second in (cmd, sweep_cmd(sweep, looking_script(tmp_path), (1, 2, 3, 4), 1, "budget.tool_calls=5")):
            r = subprocess.run(second, cwd=tmp_path, capture_output=True, text=True, timeout=300)
            assert r.returncode == 2, r.stderr[-3000:]
            [line] = r.stderr.splitlines()
            assert line.startswith(f"cab: refused: {sweep} is in use by a sweep running now (pid {first.pid} on "
                                   f"{socket.gethostname()}, started ")
            assert "nothing was run or set aside" in line
        assert (sweep / MANIFEST).read_bytes() == manifest  # no session appended by a refusal
        os.killpg(first.pid, signal.SIGCONT)
        _, err = first.communicate(timeout=900)
    finally:
        end_group(first)
    assert first.returncode == 0, err[-3000:]
    assert not list(sweep.rglob("set_aside"))
    for a in (1, 2, 3, 4):
        assert check_attempt(attempt_dir(sweep, a), {"attempt": a, "model": "scripted"}, "cli.log").state == "complete"
    assert sorted(counters(err)) == [1, 2, 3, 4]  # (item 10) each count once, on two workers
    # the lock ends with its sweep: the same command resumes it (nothing left to run)
    r = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert sum("complete already, skipped" in line for line in r.stderr.splitlines()) == 4
    assert sorted(counters(r.stderr)) == [1, 2, 3, 4]


@pytest.mark.sim
def test_a_killed_sweep_leaves_no_lock(tmp_path):
    """SIGKILL gives no process a chance to release anything: the kernel releases the lock."""
    sweep = tmp_path / "sw"
    cmd = sweep_cmd(sweep, looking_script(tmp_path), (1, 2), 1)
    first = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             start_new_session=True)
    try:
        wait_in_flight(first, sweep, (1, 2))
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()
    time.sleep(1.0)  # let the kernel reap the attempt processes (they die with their worker)
    half = (attempt_dir(sweep, 1) / "events.jsonl").exists() and not (attempt_dir(sweep, 1) / "result.json").exists()
    r = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert own_lines(r.stderr)[-1] == f"cab sweep: 2/2 attempts complete; {sweep}"
    aside = attempt_dir(sweep, 1) / "set_aside"
    assert (sorted(p.name for p in aside.iterdir()) if aside.exists() else []) == (["01-interrupted"] if half else [])


def test_the_lock_names_its_holder_and_goes_with_it(tmp_path):
    import sys

    from cab_core.sweep.manifest import LOCK, lock_sweep, unlock_sweep

    sweep = tmp_path / "sw"
    other = [sys.executable, "-c", "import sys; from cab_core.sweep.manifest import lock_sweep; lock_sweep(sys.argv[1])",
             str(sweep)]
    lock_sweep(sweep)
    try:
        lock_sweep(sweep)  # this process holds it already: no refusal of its own
        r = subprocess.run(other, capture_output=True, text=True, timeout=120)
        assert r.returncode == 1
        assert (f"SweepBusy: {sweep} is in use by a sweep running now (pid {os.getpid()} on {socket.gethostname()}, "
                "started ") in r.stderr
    finally:
        unlock_sweep(sweep)
    assert not (sweep / LOCK).exists()
    r = subprocess.run(other, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert not (sweep / LOCK).exists()  # released and removed at that process's end


@pytest.mark.sim
def test_a_full_disk_before_the_next_job_is_one_line_with_the_resume_line(tmp_path):
    """The disk fills while the first of two jobs runs: Hydra's own writes for the second job (its
    .hydra/ files) fail before cab's code runs for it; that is one line naming the file and the
    resume, not Hydra's traceback. Run again with space, both attempts complete."""
    sweep, out = _sweep_filling_its_disk(tmp_path, (1, 2))
    first = (out / "first.err").read_text()
    assert (out / "first.rc").read_text().strip() == "1", first[-3000:]
    assert "Traceback" not in first
    lines = own_lines(first)
    assert len(lines) == 2, lines
    assert "INFRASTRUCTURE FAILURE (" in lines[0]
    assert re.fullmatch(rf"cab: cannot write (\S+|in the sweep folder {re.escape(str(sweep))}): No space left on "
                        r"device; finished attempts are kept: free space, then run the same command again to resume",
                        lines[1]), lines[1]
    second = (out / "second.err").read_text()
    assert (out / "second.rc").read_text().strip() == "0", second[-3000:]
    assert own_lines(second)[-1] == f"cab sweep: 2/2 attempts complete; {sweep}"


def test_a_write_that_fails_leaves_the_old_file_and_no_temporary_copy(tmp_path, monkeypatch):
    """write_json_atomic on a full disk: the error reaches the caller, the file keeps its old
    content and no half-written temporary file is left beside it."""
    import errno

    from cab_core.attempt.records import result_format as record

    p = tmp_path / "result.json"
    record.write_json_atomic(p, {"a": 1})

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(record.os, "fsync", full)
    with pytest.raises(OSError, match="No space left"):
        record.write_json_atomic(p, {"a": 2})
    assert json.loads(p.read_text()) == {"a": 1}
    assert sorted(x.name for x in tmp_path.iterdir()) == ["result.json"]
