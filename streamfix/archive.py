"""Clean a folder of recordings: one process, a local process pool, or a Dask cluster.

What is guaranteed:

* **Same result everywhere.** Each file goes through :func:`clean_file`, a pure function
  of (input path, output path, options) that runs :func:`streamfix.cleaning.clean_recording`
  (what ``streamfix clean IN OUT`` runs), so an output does not depend on where it was made.
* **Resumable.** An output is written under a temporary name in its folder and renamed
  into place when complete, so a file at the output name is never partial; a run skips
  inputs whose output exists (unless told to overwrite).
* **No input lost.** A failing file (unreadable, corrupt, a worker that died) is recorded
  with its error; the others go on. :func:`write_summary` writes one JSON record per input
  (status ``ok`` / ``skipped`` / ``failed``, output, error, frames, seconds).

* **Ctrl-C stops at once.** Files not started are cancelled, worker processes are stopped
  (their partial files removed) and the exception goes on to the caller; outputs already
  renamed into place are complete.

Not guaranteed: order of completion (progress reports files as they finish).

Cluster: ``cluster="tcp://HOST:PORT"`` connects to a running Dask scheduler;
``"local:N"`` starts a :class:`distributed.LocalCluster` of N worker processes on
127.0.0.1 for the run. Dask is the optional extra ``streamfix[cluster]``; workers must
have streamfix installed (and the input and output paths visible).
"""
from __future__ import annotations

import contextlib
import glob
import json
import os
import time
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

from .allocator import keep_freed_memory

__all__ = [
    "ArchiveOptions",
    "ArchiveJob",
    "find_recordings",
    "plan_outputs",
    "clean_file",
    "clean_archive",
    "write_summary",
    "carry_over",
    "is_archive_input",
    "partial_path",
    "write_complete",
]

SUMMARY_NAME = "streamfix-clean-summary.json"


@dataclass(frozen=True)
class ArchiveOptions:
    """How each file is cleaned (the single-file ``streamfix clean`` options).

    window, hop, lookahead: frames, lookahead_s: seconds (None = the schedule's, at the
    file's rate). schedule: ``file`` or ``serve`` (:func:`streamfix.streaming.config.schedule_config`).
    gapfill: run the gap filler on marker sets without bones. training: reference takes for it.
    keep_filled: keep frames synthesised for sensor drops. prior: a trained prior's card
    or directory (None = the shipped one). sensor_bias: ``auto``, ``off`` or a pose-bias
    model file (:attr:`streamfix.streaming.config.EngineConfig.sensor_bias`).
    """

    window: int | None = None
    hop: int | None = None
    lookahead: int | None = None
    lookahead_s: float | None = None
    schedule: str = "file"
    gapfill: bool = True
    training: tuple[str, ...] | None = None
    keep_filled: bool = False
    prior: str | None = None
    sensor_bias: str = "auto"


@dataclass(frozen=True)
class ArchiveJob:
    """One input and where its cleaned file goes."""

    input: str
    output: str


def is_archive_input(text: str) -> bool:
    """True when ``text`` names a directory, or a glob pattern that is not itself an existing file."""
    path = Path(text)
    if path.is_dir():
        return True
    return not path.exists() and any(c in text for c in "*?[")


def find_recordings(pattern: str | Path) -> tuple[Path, list[Path]]:
    """``(root, files)``: the readable motion files in a directory (recursively) or matching a glob, sorted.

    ``root`` is the folder output paths are made relative to (the directory, or the
    pattern's fixed leading folders).
    """
    from .io import READ_FORMATS

    text = str(pattern)
    if Path(text).is_dir():
        root = Path(text)
        files = [p for p in root.rglob("*") if p.is_file()]
    else:
        parts = Path(text).parts
        fixed = [p for p in parts[: next((i for i, p in enumerate(parts) if any(c in p for c in "*?[")), len(parts))]]
        root = Path(*fixed) if fixed else Path(".")
        files = [Path(p) for p in glob.glob(text, recursive=True) if Path(p).is_file()]
    files = sorted(p for p in files if p.suffix.lower() in READ_FORMATS and not p.name.startswith("."))
    return root, files


def plan_outputs(root: Path, inputs: Sequence[Path], out_dir: str | Path) -> list[ArchiveJob]:
    """One job per input: ``out_dir`` / (input relative to ``root``), same extension when writable, else ``.sfrec``.

    Raises ``ValueError`` when an output would overwrite an input or two inputs share an output.
    """
    from .io import WRITE_FORMATS

    out_dir = Path(out_dir)
    jobs, seen = [], {}
    resolved_inputs = {p.resolve() for p in inputs}
    for path in inputs:
        rel = path.relative_to(root) if path.is_relative_to(root) else Path(path.name)
        ext = path.suffix.lower() if path.suffix.lower() in WRITE_FORMATS else ".sfrec"
        out = out_dir / rel.with_suffix(ext)
        if out.resolve() in resolved_inputs:
            raise ValueError(f"{out}: the output would replace an input; choose another OUT_DIR")
        if out in seen:
            raise ValueError(f"{seen[out]} and {path} would both be written to {out}")
        seen[out] = path
        jobs.append(ArchiveJob(str(path), str(out)))
    return jobs


def partial_path(path: str | Path, pid: int | None = None) -> Path:
    """Where ``path`` is written before it is complete: a hidden ``.STEM.part-PID.EXT`` beside it.

    Same folder (so ``os.replace`` into place is atomic), the same extension (the writer picks
    the format from it), a leading dot (never found as a recording). ``pid``: the writing
    process (default this one), so the name of a killed writer's leftover can be found.
    """
    out = Path(path)
    return out.with_name(f".{out.stem}.part-{os.getpid() if pid is None else pid}{out.suffix}")


def write_complete(motion, path: str | Path) -> None:
    """Write ``motion`` (:func:`streamfix.io.write_motion`, format from the extension) to ``path``
    under :func:`partial_path` and rename it into place: ``path`` never holds half a file (a
    crash or Ctrl-C mid-write leaves the old one, if any), and no partial file is left behind.
    Errors raise as the writer's (OSError / ValueError), the partial file removed."""
    from .io import write_motion

    out = Path(path)
    tmp = partial_path(out)
    try:
        write_motion(motion, tmp)
        if not tmp.is_file() or tmp.stat().st_size == 0:
            raise OSError(f"{out}: the writer reported success but no file was written")
        os.replace(tmp, out)  # atomic within a folder
    finally:
        tmp.unlink(missing_ok=True)


_PRIOR_SET: list[str | None] = [None]  # the prior this process last made its default


def clean_file(input_path: str, output_path: str, options: ArchiveOptions = ArchiveOptions()) -> dict:
    """Clean one recording into ``output_path`` (written under a temporary name, then renamed).

    Never raises: returns ``{"input", "output", "status": "ok" | "failed", "error",
    "frames", "seconds"}`` (frames written; seconds of CPU time in this process).
    """
    keep_freed_memory()  # a pool or cluster worker is a process of its own (streamfix.allocator)
    t0 = time.process_time()
    record = {"input": str(input_path), "output": str(output_path), "status": "failed", "error": None,
              "frames": 0, "seconds": 0.0}
    out = Path(output_path)
    try:
        from .cleaning import clean_recording
        from .io import read_motion
        from .streaming.config import schedule_config

        if options.prior != _PRIOR_SET[0]:
            from .prior.runtime import set_default_prior

            set_default_prior(options.prior)
            _PRIOR_SET[0] = options.prior
        motion = read_motion(input_path)
        config = schedule_config(options.schedule, motion.rate_hz, window=options.window, hop=options.hop,
                                 lookahead=options.lookahead, lookahead_s=options.lookahead_s,
                                 sensor_bias=options.sensor_bias)
        result = clean_recording(motion, config, gapfill=options.gapfill,
                                 training=list(options.training) if options.training else None,
                                 keep_filled=options.keep_filled)
        out.parent.mkdir(parents=True, exist_ok=True)
        write_complete(result.motion, out)
        record.update(status="ok", frames=int(result.motion.n_frames))
    except Exception as exc:  # one bad file must not stop an archive: report it, go on
        record["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        record["seconds"] = round(time.process_time() - t0, 4)
    return record


def _is_complete(path: str) -> bool:
    p = Path(path)
    return p.is_file() and p.stat().st_size > 0


def _ignore_sigint() -> None:
    """Pool worker initializer: Ctrl-C is the parent's to handle (it stops the workers itself),
    so a terminal's SIGINT to the whole process group does not kill a worker mid-write."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _local_results(jobs: list[ArchiveJob], options: ArchiveOptions, n_jobs: int) -> Iterator[dict]:
    if n_jobs <= 1:
        for job in jobs:
            yield clean_file(job.input, job.output, options)
        return
    import multiprocessing

    # spawn: a forked child would inherit onnxruntime / BLAS thread state of the parent
    pool = ProcessPoolExecutor(max_workers=n_jobs, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_ignore_sigint)
    futures: dict[Future, ArchiveJob] = {}
    try:
        for j in jobs:
            futures[pool.submit(clean_file, j.input, j.output, options)] = j
        for fut in as_completed(futures):
            yield _result_or_failure(fut, futures[fut])
    except BaseException:  # Ctrl-C, an error, or the consumer stopped early (GeneratorExit)
        _stop_pool(pool, [j for f, j in futures.items() if not f.done()])
        raise
    pool.shutdown(wait=True)


def _stop_pool(pool: ProcessPoolExecutor, unfinished: list[ArchiveJob], grace_s: float = 5.0) -> None:
    """Stop a pool now, without waiting for its queued or running files: cancel what has not
    started, terminate the workers (killed if still alive after ``grace_s``), and remove the
    partial files the terminated workers leave behind. A plain ``shutdown()`` waits for every
    queued file, and can wait forever on a worker idle on its call queue after a Ctrl-C."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # before shutdown() drops them
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        if proc.is_alive():
            proc.terminate()
    deadline = time.monotonic() + grace_s
    for proc in processes:
        proc.join(max(0.0, deadline - time.monotonic()))
    for proc in processes:
        if proc.is_alive():
            proc.kill()
            proc.join(1.0)
    for job in unfinished:  # a worker killed mid-file never ran clean_file's cleanup
        for proc in processes:
            if proc.pid is not None:
                partial_path(job.output, proc.pid).unlink(missing_ok=True)
    # let the pool's manager thread see its workers gone and close its wake-up pipe: at exit,
    # Python 3.11 wakes every pool's manager and raced its closing ("Exception ignored ... Bad
    # file descriptor" printed after the user's Ctrl-C)
    if manager is not None and manager.is_alive():
        manager.join(grace_s)


def _result_or_failure(fut, job: ArchiveJob) -> dict:
    """A job's record; a worker that died (or a lost task) is a failed record, not a lost input."""
    try:
        return fut.result()
    except Exception as exc:
        return {"input": job.input, "output": job.output, "status": "failed",
                "error": f"worker failed: {type(exc).__name__}: {exc}", "frames": 0, "seconds": 0.0}


def _cluster_results(jobs: list[ArchiveJob], options: ArchiveOptions, address: str) -> Iterator[dict]:
    try:
        from distributed import Client, LocalCluster, as_completed as dask_completed
    except ImportError:
        raise RuntimeError("--cluster needs Dask: pip install 'streamfix[cluster]'") from None
    cluster = None
    if address.startswith("local:"):
        try:
            n = int(address.split(":", 1)[1])
            if n < 1:
                raise ValueError
        except ValueError:
            raise ValueError(f"--cluster {address!r}: expected local:N with N >= 1 workers") from None
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
        client = Client(cluster)
    else:
        try:
            client = Client(address, timeout=10)
        except (OSError, TimeoutError) as exc:
            raise RuntimeError(f"--cluster {address}: cannot reach the Dask scheduler: {exc}") from None
    try:
        futures = client.map(clean_file, [j.input for j in jobs], [j.output for j in jobs], options=options,
                             pure=False, retries=0)
        by_key = {f.key: j for f, j in zip(futures, jobs)}
        for fut in dask_completed(futures):
            yield _result_or_failure(fut, by_key[fut.key])
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def clean_archive(
    jobs: Iterable[ArchiveJob],
    options: ArchiveOptions = ArchiveOptions(),
    *,
    n_jobs: int = 1,
    cluster: str | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int, dict], None] | None = None,
) -> list[dict]:
    """Clean every job's input; one record per job, in the jobs' order.

    Jobs whose output is complete are skipped (status ``skipped``) unless ``overwrite``.
    ``n_jobs`` processes on this machine, or ``cluster`` (a Dask scheduler address or
    ``local:N``). ``progress(done, total, record)`` is called as each file finishes.
    """
    jobs = list(jobs)
    if n_jobs < 1:
        raise ValueError(f"jobs must be >= 1 processes, got {n_jobs}")
    records: dict[tuple[str, str], dict] = {}
    todo, done = [], 0
    for job in jobs:
        if not overwrite and _is_complete(job.output):
            rec = {"input": job.input, "output": job.output, "status": "skipped",
                   "error": None, "frames": None, "seconds": 0.0}
            records[(job.input, job.output)] = rec
            done += 1
            if progress is not None:
                progress(done, len(jobs), rec)
        else:
            todo.append(job)
    results = _cluster_results(todo, options, cluster) if cluster else _local_results(todo, options, n_jobs)
    try:
        for rec in results:
            records[(rec["input"], rec["output"])] = rec
            done += 1
            if progress is not None:
                progress(done, len(jobs), rec)
    finally:  # an exception here (Ctrl-C in progress()) stops the workers now, not when the generator is collected
        results.close()
    return [records[(j.input, j.output)] for j in jobs]


def write_summary(records: list[dict], path: str | Path, options: ArchiveOptions | None = None) -> None:
    """The per-input records as JSON (written under a temporary name, then renamed).

    Raises OSError naming ``path`` (not the temporary name, which the caller never gave).
    """
    path = Path(path)
    counts = {s: sum(r["status"] == s for r in records) for s in ("ok", "skipped", "failed")}
    doc = {"inputs": len(records), **counts, "options": asdict(options) if options else None, "files": records}
    tmp = partial_path(path)
    try:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


def carry_over(records: list[dict], previous_summary: str | Path) -> list[dict]:
    """Skipped records take frames and seconds from an earlier run's summary (same input and output)."""
    try:
        earlier = json.loads(Path(previous_summary).read_text()).get("files", [])
    except (OSError, ValueError, AttributeError):
        return records
    done = {(r.get("input"), r.get("output")): r for r in earlier if isinstance(r, dict) and r.get("status") == "ok"}
    out = []
    for rec in records:
        prev = done.get((rec["input"], rec["output"]))
        if rec["status"] == "skipped" and prev is not None:
            rec = {**rec, "frames": prev.get("frames"), "seconds": prev.get("seconds", 0.0)}
        out.append(rec)
    return out

