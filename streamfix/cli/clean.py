"""``streamfix clean IN OUT``: clean a recorded file offline with the streaming engine.

The file is read with :func:`streamfix.io.read_motion`, passed frame by frame through
the same :class:`~streamfix.streaming.engine.StreamEngine` that ``streamfix serve``
runs (synchronous mode, so the result is deterministic and equals serve's ``clean``
output), and written with :func:`streamfix.io.write_motion` (format from OUT's
extension). Marker files without bones (C3D) first go through the gap filler
(``streamfix.gapfill.fill_motion_gaps``, Li et al. PCA trained on the take's own
observed samples plus ``--training`` reference takes): offline the filler sees both
ends of every gap. Filled samples are flagged recovered in the output (kept by
``.sfrec``; a C3D or CSV file has no such flag) and counted in the summary. A progress bar is drawn
on stderr when it is a terminal; one summary line goes to stdout.

OUT is checked before any solving (writable format and directory, not the input, an
existing file only with ``--overwrite``); a failed write prints one line and exits 1.

``streamfix clean DIR OUT_DIR`` (or a quoted glob, ``'takes/*.bvh'``) cleans every
recording found into OUT_DIR (sub-folders kept) with :mod:`streamfix.archive`: one line
of progress per file on stderr, ``--jobs N`` worker processes or ``--cluster ADDRESS`` on
Dask, outputs that already exist skipped (a rerun resumes), a JSON summary per input, exit
1 if any file failed.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

import numpy as np

from .options import add_sensor_bias_argument

HELP = "Clean a recorded motion file offline (the engine of serve's clean output, on a schedule for files)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", metavar="IN", help="motion file to clean (.csv Kinect v2, .bvh, .c3d, .sfrec)")
    parser.add_argument("output", metavar="OUT", help="where to write the cleaned motion (format from the extension)")
    parser.add_argument("--window", type=int, default=None, metavar="W",
                        help="frames per solved window (default: 20 s at the file's rate; serve's schedule: 2 s)")
    parser.add_argument("--hop", type=int, default=None, metavar="H",
                        help="frames between window solves (default: 18 s, at most lookahead+1)")
    parser.add_argument("--lookahead", default=None, metavar="L",
                        help="lookahead per output frame, as in serve: seconds (2 or 2s) or frames (60f); "
                             "default 19 s (a file has no latency bound; serve's 0.5 s gives serve's clean topic)")
    parser.add_argument("--schedule", choices=("file", "serve"), default="file",
                        help="window schedule: 'file' (default: 20 s windows, 19 s lookahead, a window every 18 s) or "
                             "'serve' (serve's clean topic exactly: 0.5 s lookahead, a window every 1/3 s); "
                             "--window/--hop/--lookahead override either")
    parser.add_argument("--skeleton-lengths", default=None, metavar="LENGTHS",
                        help="fixed bone lengths in metres: comma-separated B values, or a file of them "
                             "(one per line or comma-separated), in the skeleton's bone order; the output holds "
                             "them (without it, tracked bones keep a few per cent of the sensor's length play)")
    parser.add_argument("--keep-filled", action="store_true",
                        help="also write the frames synthesised for dropped sensor frames (timestamp gaps)")
    parser.add_argument("--no-gapfill", action="store_true",
                        help="do not run the gap filler on marker files before cleaning")
    parser.add_argument("--training", action="append", default=None, metavar="FILE_OR_DIR",
                        help="reference takes of the same marker set for the gap filler, which runs on "
                             "marker files without bones (files or directories; repeatable)")
    parser.add_argument("--overwrite", action="store_true", help="replace OUT if it exists (never the input)")
    parser.add_argument("--prior", default=None, metavar="PATH",
                        help="learned prior to use: a model card .json or a directory holding one, as written by "
                             "`streamfix train-prior --out DIR` (default: the shipped model)")
    add_sensor_bias_argument(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="IN a folder or glob: clean N files at once in worker processes (default 1)")
    parser.add_argument("--cluster", default=None, metavar="ADDRESS",
                        help="IN a folder or glob: clean on a Dask cluster (scheduler address tcp://HOST:PORT, "
                             "or local:N to start N local workers); needs the 'cluster' extra")
    parser.add_argument("--summary", default=None, metavar="PATH",
                        help="IN a folder or glob: where to write the per-file JSON summary "
                             "(default OUT/streamfix-clean-summary.json)")


def _parse_lengths(text: str, n_bones: int) -> tuple[float, ...]:
    path = Path(text)
    source = path.read_text() if path.is_file() else text
    items = [t for t in source.replace("\n", ",").replace(";", ",").split(",") if t.strip()]
    try:
        values = tuple(float(t) for t in items)
    except ValueError:
        raise ValueError(f"--skeleton-lengths: expected {n_bones} numbers (metres), got {text!r}") from None
    if len(values) != n_bones:
        raise ValueError(f"--skeleton-lengths: the skeleton has {n_bones} bones, got {len(values)} lengths")
    if not all(np.isfinite(v) and v > 0 for v in values):
        raise ValueError("--skeleton-lengths: lengths must be positive metres")
    return values


def _check_training(paths: list[str] | None) -> str | None:
    """Why ``--training`` cannot be used (a path that is neither a file nor a folder), or None.

    Checked up front for every input: the gap filler reads the takes only for a marker set
    with gaps, so a mistyped path would otherwise pass unnoticed on most files.
    """
    for path in paths or ():
        if not (Path(path).is_file() or Path(path).is_dir()):
            return f"--training {path}: training take not found (expected a motion file or a directory)"
    return None


class _Progress:
    """A one-line progress bar on stderr, drawn only when stderr is a terminal."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label = label
        self.enabled = enabled and sys.stderr.isatty()
        self.t0 = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        width = 30
        fill = int(width * done / max(total, 1))
        rate = done / max(time.monotonic() - self.t0, 1e-9)
        sys.stderr.write(f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {done}/{total} frames {rate:.0f} fps")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()


def run(args: argparse.Namespace) -> int:
    from ..archive import is_archive_input

    if is_archive_input(args.input):  # a folder or a glob: IN_DIR OUT_DIR
        return _run_archive(args)
    if args.jobs != 1 or args.cluster is not None or args.summary is not None:
        print("streamfix clean: --jobs, --cluster and --summary apply when IN is a folder or a glob", file=sys.stderr)
        return 2
    from ..io import WRITE_FORMATS, check_writable, read_motion
    from ..streaming.config import schedule_config
    from ..cleaning import clean_recording
    from ..streaming.offline import WindowSolverError
    from .outputs import check_output

    try:  # before any solving: a bad output must not cost the whole run
        check_output(args.output, formats=WRITE_FORMATS, inputs=[args.input], overwrite=args.overwrite)
    except (OSError, ValueError) as exc:
        print(f"streamfix clean: {exc}", file=sys.stderr)
        return 2
    bad_training = _check_training(args.training)
    if bad_training:
        print(f"streamfix clean: {bad_training}", file=sys.stderr)
        return 2
    from .options import apply_prior_option, check_sensor_bias_option

    if not apply_prior_option("clean", args.prior) or not check_sensor_bias_option("clean", args.sensor_bias):
        return 2

    try:
        motion = read_motion(args.input)
    except (OSError, ValueError) as exc:
        print(f"streamfix clean: {exc}", file=sys.stderr)
        return 1
    try:  # the output format may not hold this layout (BVH needs a tree): say so before solving
        check_writable(motion.skeleton, args.output)
    except ValueError as exc:
        print(f"streamfix clean: cannot write {args.output}: {exc}", file=sys.stderr)
        return 2
    n_frames_in = motion.n_frames
    if motion.meta.get("nonfinite_joints"):  # said even with --quiet: the file is not what its states claim
        print(f"streamfix clean: warning: {args.input}: {motion.meta['nonfinite_joints']} joint-sample(s) flagged "
              f"seen but with a NaN/inf coordinate, read as missing", file=sys.stderr)
    try:
        lengths = solver_config = None
        if args.skeleton_lengths is not None:
            from ..core.pipeline import PipelineConfig

            lengths = _parse_lengths(args.skeleton_lengths, motion.skeleton.n_bones)
            # lengths the user fixed are held: no length play (core/length_tolerance.py)
            solver_config = PipelineConfig(projection_tolerance=0.0)
        seconds, frames = _lookahead(args)
        config = schedule_config(args.schedule, motion.rate_hz, window=args.window, hop=args.hop, lookahead=frames,
                                 lookahead_s=seconds, bone_lengths=lengths, solver_config=solver_config,
                                 sensor_bias=args.sensor_bias)
    except ValueError as exc:
        print(f"streamfix clean: {exc}", file=sys.stderr)
        return 2
    progress = _Progress(Path(args.input).name, not args.quiet)
    try:
        result = clean_recording(motion, config, gapfill=not args.no_gapfill, training=getattr(args, "training", None),
                                 keep_filled=args.keep_filled, progress=progress)
    except (OSError, ValueError, WindowSolverError) as exc:
        print(f"streamfix clean: {exc}", file=sys.stderr)
        return 1
    finally:
        progress.close()
    source, cleaned, metrics, notes, gapfilled = (
        result.source, result.motion, result.metrics, result.notes, result.gapfilled)
    from ..archive import partial_path, write_complete

    try:
        write_complete(cleaned, args.output)  # beside OUT, then renamed: OUT is never half written
    except (OSError, ValueError) as exc:
        tmp = str(partial_path(args.output))  # a writer's error may name the file it wrote
        print(f"streamfix clean: cannot write {args.output}: {str(exc).replace(tmp, str(args.output))}",
              file=sys.stderr)
        return 1
    if metrics.get("solver_errors", 0):  # a partly failed cleaning is said even with --quiet
        print(f"streamfix clean: warning: {metrics['solver_errors']} window(s) failed to solve "
              f"(first: {metrics.get('first_solver_error')})", file=sys.stderr)
    if not args.quiet:
        print(_summary(args.input, source, cleaned, metrics, config, notes, gapfilled))
    return 0 if cleaned.n_frames >= n_frames_in else 1


def _summary(path, source, cleaned, metrics: dict, config, notes: list[str], gapfilled=None) -> str:
    """One line: frames, joints recovered, gap-filled samples, mean change (mm) over the input's observed joints."""
    recovered = int(cleaned.recovered.sum()) if cleaned.recovered is not None else 0
    total = cleaned.n_frames * cleaned.n_joints
    change = float("nan")
    if cleaned.n_frames == source.n_frames:
        d = np.linalg.norm(cleaned.positions - source.positions, axis=2)
        obs = source.observed & np.isfinite(d)
        if obs.any():
            change = float(d[obs].mean() * 1000.0)
    extra = f"; {'; '.join(notes)}" if notes else ""
    return (
        f"{Path(path).name}: {cleaned.n_frames} frames x {cleaned.n_joints} joints, "
        f"{recovered} joint-frames recovered ({100.0 * recovered / max(total, 1):.1f} %), "
        f"{0 if gapfilled is None else int(gapfilled.sum())} gap samples filled, "
        f"mean change {change:.1f} mm, {metrics.get('frames_filled', 0)} dropped frames filled "
        f"(window {config.window}, hop {config.hop}, lookahead {config.lookahead} frames){extra}"
    )


def _lookahead(args: argparse.Namespace) -> tuple[float | None, int | None]:
    """``--lookahead`` as (seconds, frames), one of them None (both when not given); the
    syntax of serve's option. Raises ValueError naming what is wrong."""
    from ..service.engines import parse_lookahead

    return (None, None) if args.lookahead is None else parse_lookahead(args.lookahead)


def _run_archive(args: argparse.Namespace) -> int:
    """``streamfix clean DIR|'GLOB' OUT_DIR``: every recording, progress on stderr, a JSON summary; 1 if any failed."""
    from ..archive import (ArchiveOptions, SUMMARY_NAME, carry_over, clean_archive, find_recordings, plan_outputs,
                           write_summary)

    def fail(message: str) -> int:
        print(f"streamfix clean: {message}", file=sys.stderr)
        return 2

    if args.skeleton_lengths is not None:
        return fail("--skeleton-lengths applies to one file (one skeleton), not to a folder of recordings")
    if args.jobs < 1:
        return fail(f"--jobs must be >= 1 processes, got {args.jobs}")
    if args.cluster is not None and args.jobs != 1:
        return fail("--jobs and --cluster exclude each other (a cluster's size is its workers)")
    out_dir = Path(args.output)
    if out_dir.exists() and not out_dir.is_dir():
        return fail(f"{out_dir}: IN is a folder or glob, so OUT must be a folder; {out_dir} is a file")
    root, inputs = find_recordings(args.input)
    inputs = [p for p in inputs if not p.resolve().is_relative_to(out_dir.resolve())]  # not last run's outputs
    if not inputs:
        return fail(f"{args.input}: no motion files found (.csv, .bvh, .c3d, .sfrec)")
    bad_training = _check_training(args.training)
    if bad_training:
        return fail(bad_training)
    created = not out_dir.exists()
    try:
        jobs = plan_outputs(root, inputs, out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
    except (OSError, ValueError) as exc:
        return fail(str(exc))
    summary = Path(args.summary) if args.summary else out_dir / SUMMARY_NAME
    if args.summary:  # before any cleaning (OUT exists now): an unwritable summary must not cost the whole run
        from .outputs import check_output

        try:
            check_output(summary, formats=(summary.suffix.lower(),), overwrite=True)
        except (OSError, ValueError) as exc:
            if created:
                with contextlib.suppress(OSError):
                    out_dir.rmdir()  # only the empty folder this run made
            return fail(f"--summary {exc}")
    from .options import apply_prior_option, check_sensor_bias_option

    if not apply_prior_option("clean", args.prior):  # checked here once, before any worker loads it
        return 2
    if not check_sensor_bias_option("clean", args.sensor_bias):
        return 2
    from ..sensor_bias.shipped import is_model_path

    try:
        seconds, frames = _lookahead(args)
    except ValueError as exc:
        return fail(str(exc))
    options = ArchiveOptions(
        window=args.window, hop=args.hop, lookahead=frames, lookahead_s=seconds, schedule=args.schedule,
        gapfill=not args.no_gapfill,
        training=tuple(str(Path(t).resolve()) for t in args.training) if args.training else None,
        keep_filled=args.keep_filled, prior=str(Path(args.prior).resolve()) if args.prior else None,
        sensor_bias=str(Path(args.sensor_bias).resolve()) if is_model_path(args.sensor_bias) else args.sensor_bias,
    )
    t0 = time.monotonic()

    def progress(done: int, total: int, record: dict) -> None:
        if args.quiet:
            return
        what = record["status"] if record["status"] != "failed" else f"FAILED: {record['error']}"
        frames = f", {record['frames']} frames" if record.get("frames") else ""
        print(f"[{done}/{total}] {Path(record['input']).name}: {what}{frames} ({time.monotonic() - t0:.0f} s)",
              file=sys.stderr, flush=True)

    try:
        records = clean_archive(jobs, options, n_jobs=args.jobs, cluster=args.cluster, overwrite=args.overwrite,
                                progress=progress)
    except (RuntimeError, ValueError, OSError) as exc:
        print(f"streamfix clean: {exc}", file=sys.stderr)
        return 1
    records = carry_over(records, summary)  # a resumed run still reports every output's frames
    try:
        write_summary(records, summary, options)
    except OSError as exc:
        print(f"streamfix clean: cannot write the summary {summary}: {exc}", file=sys.stderr)
        return 1
    failed = [r for r in records if r["status"] == "failed"]
    if not args.quiet or failed:
        ok = sum(r["status"] == "ok" for r in records)
        skipped = sum(r["status"] == "skipped" for r in records)
        print(f"{len(records)} recordings: {ok} cleaned, {skipped} already done, {len(failed)} failed "
              f"({time.monotonic() - t0:.1f} s); summary in {summary}", file=sys.stdout if not failed else sys.stderr)
    return 1 if failed else 0

