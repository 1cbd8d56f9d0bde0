"""``markergraph map``: a log (or the bundled sample) to a corrected marker map on disk."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from markergraph.cli._commands import summary
from markergraph.cli._settings import add_settings, add_verbosity, say_notes, settings_from
from markergraph.common import SettingsError
from markergraph.common.files import check_output_folder
from markergraph.common.progress import ProgressBar, Stages
from markergraph.settings import config_toml, map_config

if TYPE_CHECKING:
    from markergraph.common import Note
    from markergraph.estimator import MapError
    from markergraph.plotter import Plotter
    from markergraph.records import MapRun, MethodResult
    from markergraph.settings import MapConfig

# The mapping itself (GTSAM, matplotlib, the writers) is imported by the command's run, once
# its arguments are checked: a missing log is said without waiting for them.

SUMMARY = summary("map")
DEFAULT_SAMPLE = "corridor-loop"
EXIT_NOT_OK = 4  # --strict: a method's verdict is "suspect" or "failed"
# Exactly what write_results leaves out without plots (a test compares the two folders).
NO_PLOTS_HELP = (
    "skip the pictures: map.png, map.svg, comparison.png and diagnostics.png, and each "
    "method's map.png and map.svg (a 3-D map: its map.png); report.html is still written, "
    "without them"
)


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("map", help=SUMMARY, description=SUMMARY)
    parser.add_argument(
        "logs",
        type=Path,
        nargs="*",
        metavar="LOG",
        help="an .mcap file, a rosbag2 folder, a ROS 1 .bag or markergraph detect's .jsonl "
        "output; several logs of one place make one map (default: the bundled "
        f"{DEFAULT_SAMPLE} sample, rendered once into the cache)",
    )
    parser.add_argument(
        "--prior", type=Path, metavar="MAP.json",
        help="refine a saved map: its markers enter with their covariances",
    )  # fmt: skip
    add_executor(parser)
    parser.add_argument(
        "--out", type=Path, default=None, help="result folder (default: map-<log name> here)"
    )
    parser.add_argument("--force", action="store_true", help="replace an existing result folder")
    add_no_cache(parser)
    parser.add_argument(
        "--no-plots", action="store_true",
        help=NO_PLOTS_HELP,
    )  # fmt: skip
    parser.add_argument(
        "--strict", action="store_true",
        help=f"exit {EXIT_NOT_OK} when a method's verdict is not ok (the folder is still written)",
    )  # fmt: skip
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="print the settings in effect as a TOML file for --config, and stop",
    )
    add_verbosity(parser)
    add_settings(parser, "map")


LOCALIZE = summary("localize")
LOCALIZE_FILES = (
    "writes into --out: trajectory.tum (the path, map frame), localization.json (every pose with "
    "its covariance, moved and new markers), overlay.mcap (the map and path for Foxglove), "
    "map.png (the map with its ellipses, the path, moved markers as arrows from their old to "
    "their new place), report.json and report.html (one page that opens offline), and "
    "ground_truth.tum when the log carries truth"
)


def add_localize_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "localize", help=LOCALIZE, description=f"{LOCALIZE}; {LOCALIZE_FILES}"
    )
    parser.add_argument("log", type=Path, help="an .mcap file, a rosbag2 folder or a ROS 1 .bag")
    parser.add_argument("--map", type=Path, required=True, metavar="MAP.json",
                        help="the saved map (markergraph map's map.json)")  # fmt: skip
    parser.add_argument("--out", type=Path, required=True, help="result folder")
    parser.add_argument("--force", action="store_true", help="replace an existing result folder")
    parser.add_argument("--no-plots", action="store_true", help="skip map.png")
    add_no_cache(parser)
    add_verbosity(parser)
    add_settings(parser, "localize")


def add_no_cache(parser: argparse.ArgumentParser) -> None:
    """Read the log even when the cache holds its observations."""
    parser.add_argument(
        "--no-cache", action="store_true",
        help="read the log again rather than take its observations (and the camera delay and "
        "odometry scale found on them) from the cache folder; MARKERGRAPH_NO_CACHE=1 does the same",
    )  # fmt: skip


def _plotter(args: argparse.Namespace, methods: int = 1) -> Plotter:
    """Where figures are wanted, a plotter whose processes start now, importing matplotlib while
    the log is read and the map solved (:class:`~markergraph.plotter.Plotter`): two for several
    methods' figures (on the bundled sample, ``--method all`` drew its eight in 3.8 s in one)."""
    from markergraph.plotter import Plotter

    return Plotter() if args.no_plots else Plotter.start(processes=1 if methods == 1 else 2)


def run_localize(args: argparse.Namespace) -> int:
    from markergraph.frontend.logs.files import check_exists

    values = settings_from(args, "localize")
    check_exists(Path(args.log))  # said at once, before the mapping's imports
    from markergraph.localize_accuracy import accuracy_lines, accuracy_of
    from markergraph.markermap import MarkerMap
    from markergraph.report_page import REPORT_PAGE
    from markergraph.results import write_localization
    from markergraph.run import localize_log
    from markergraph.sessions import settings_for_map

    check_output_folder(args.out, [args.log, args.map], force=args.force)
    saved = MarkerMap.load(args.map)
    config = map_config(settings_for_map(values, saved, args.map))
    with _plotter(args) as plotter:
        with ProgressBar(f"reading {Path(args.log).name}", quiet=args.quiet) as bar:
            stages = Stages(quiet=args.quiet, verbose=args.verbose, before=bar.close)
            run = localize_log(args.log, saved, args.map, config, progress=bar, stage=stages,
                               cache=not args.no_cache)  # fmt: skip
        stages(f"writing {args.out}/")
        written = write_localization(run, args.out, force=args.force, plots=not args.no_plots,
                                     plotter=plotter)  # fmt: skip
    stages.close()
    loc = run.localization
    path = len(run.path) if run.path is not None else len(loc.trajectory)
    print(
        f"{len(loc.trajectory)} poses localised in the map of {args.map} (the frames with its "
        f"markers); {path} in trajectory.tum with the odometry between them"
    )
    for line in accuracy_lines(accuracy_of(loc, run.ate_m, run.ate_aligned_m)):
        print(line)
    for m in loc.moved:
        print(f"moved: marker {m.marker_id} by {100 * m.displacement_m:.1f} cm")
    for i in sorted(loc.new):
        print(f"new: marker {i}")
    say_notes(run.notes, quiet=args.quiet)
    print(f"wrote {len(written)} files to {args.out}/ (open {Path(args.out) / REPORT_PAGE})")
    return 0


def add_executor(parser: argparse.ArgumentParser) -> None:
    """Where the logs' front ends run."""
    parser.add_argument(
        "--executor", choices=["local", "ray"], default="local",
        help="run each log's front end in local processes (--workers) or as Ray tasks",
    )  # fmt: skip
    parser.add_argument(
        "--ray-address", metavar="ADDRESS",
        help="the Ray cluster to join (default: $RAY_ADDRESS, else a local Ray instance)",
    )  # fmt: skip


def _sample(render: bool) -> Path:
    """The bundled sample's log, rendered first if ``render`` and not yet cached; its modules
    (the simulator's) are imported only for it."""
    from markergraph.datasets.samples import sample_log, sample_path

    return sample_log(DEFAULT_SAMPLE) if render else sample_path(DEFAULT_SAMPLE)


def run(args: argparse.Namespace) -> int:
    from markergraph.frontend.logs.files import check_exists

    config = map_config(settings_from(args, "map"))
    if args.print_config:
        print(config_toml(config.values), end="")
        return 0
    for log in args.logs:  # said at once, before the mapping's imports
        check_exists(Path(log))
    from markergraph.formats.observations import is_observation_file
    from markergraph.markermap import MarkerMap
    from markergraph.report_page import REPORT_PAGE
    from markergraph.results import write_results
    from markergraph.run import map_logs
    from markergraph.run3d import wants_3d
    from markergraph.verdicts import Verdict

    logs = list(args.logs) or [_sample(render=False)]
    out = args.out or Path(f"map-{Path(logs[0]).stem}")
    # Before any work (a sample's rendering included): never over the input or a user's folder.
    check_output_folder(out, [*logs, *([args.prior] if args.prior else [])], force=args.force)
    prior = MarkerMap.load(args.prior) if args.prior is not None else None
    if prior is not None:
        from markergraph.sessions import settings_for_map

        config = map_config(settings_for_map(settings_from(args, "map"), prior, args.prior))
    if not args.logs:
        logs = [_sample(render=True)]
        print(f"no log given: mapping the bundled {DEFAULT_SAMPLE} sample ({logs[0]})")
    if args.logs and not is_observation_file(logs[0]):
        three_d, why = wants_3d(logs[0], config)
    else:  # the sample, or detect's output (2-D observations)
        three_d, why = config.dimensions == "3", None
    if three_d:
        if len(logs) > 1 or prior is not None:
            raise SettingsError("a 3-D map is made from one log (several logs and --prior are 2-D)")
        return _run_3d(args, logs[0], out, config, [why] if why else [])
    with _plotter(args, len(config.methods)) as plotter:
        with ProgressBar(f"reading {Path(logs[0]).name}", quiet=args.quiet) as bar:
            stages = Stages(quiet=args.quiet, verbose=args.verbose, before=bar.close)
            result = map_logs(logs, config, prior=prior, executor=args.executor,
                              address=args.ray_address, progress=bar, stage=stages,
                              cache=not args.no_cache)  # fmt: skip
        stages(f"writing {out}/")
        written = write_results(result, out, force=args.force, plots=not args.no_plots,
                                plotter=plotter)  # fmt: skip
    stages.close()
    _print_summary(result, quiet=args.quiet)
    print(f"wrote {len(written)} files to {out}/")
    print(f"open {out / REPORT_PAGE}")
    if args.strict and result.judgement.verdict is not Verdict.OK:
        return EXIT_NOT_OK
    return 0


def _run_3d(
    args: argparse.Namespace, log: Path, out: Path, config: MapConfig, notes: list[Note]
) -> int:
    from markergraph.report_page import REPORT_PAGE
    from markergraph.results3d import write_results_3d
    from markergraph.run3d import map_log_3d
    from markergraph.verdicts import Verdict

    stages = Stages(quiet=args.quiet, verbose=args.verbose)
    with _plotter(args) as plotter:
        run = map_log_3d(log, config, notes=notes, stage=stages)
        stages(f"writing {out}/")
        written = write_results_3d(run, out, force=args.force, plots=not args.no_plots,
                                   plotter=plotter)  # fmt: skip
    stages.close()
    report_page = out / REPORT_PAGE
    tag_map = run.tag_map
    walls = sum(1 for m in run.marker_map.markers.values())
    print(
        f"{run.frames_read:,} rig frames ({tag_map.frames_skipped:,} placed by no tag), "
        f"{run.views_read:,} tag views; 3-D map of {len(tag_map.tags)} tags ({walls} on walls), "
        f"home tag {tag_map.home_id if tag_map.home_id is not None else '(the survey frame)'}, "
        f"reprojection RMS {tag_map.reprojection_rms_px:.2f} px"
    )
    for camera in tag_map.cameras.values():
        how = "estimated" if camera.estimated else "given"
        print(f"camera {camera.name} ({camera.topic}): mount {how}, {camera.n_views:,} views")
    print(f"verdict {run.marker_map.method}: {run.judgement.verdict.value}", end="")
    print("".join(f"\n  - {reason.text}" for reason in run.judgement.reasons))
    say_notes([*run.notes, *tag_map.notes], quiet=args.quiet)
    print(f"wrote {len(written)} files to {out}/")
    print(f"open {report_page}")
    if args.strict and run.judgement.verdict is not Verdict.OK:
        return EXIT_NOT_OK
    return 0


def _error_columns(method_result: MethodResult, home_fixed: MapError) -> str:
    """A method's aligned and home-fixed marker RMSE, its ATE (aligned and home-fixed) and over
    how many poses."""
    aligned = method_result.map_error_aligned
    trajectory = method_result.trajectory_error
    true_path = method_result.true_path
    columns = [
        f"{aligned.rmse_position_m:>16.3f}" if aligned else f"{'-':>16}",
        f"{home_fixed.rmse_position_m:>19.3f}",
    ]
    if trajectory is not None and true_path is not None:
        columns += [f"{trajectory.ate_aligned_rmse_m:>15.3f}", f"{trajectory.ate_rmse_m:>18.3f}",
                    f"{len(true_path):>6}"]  # fmt: skip
    else:
        columns += [f"{'-':>15}", f"{'-':>18}", f"{'-':>6}"]
    return " " + " ".join(columns)


def _print_summary(result: MapRun, *, quiet: bool = False) -> None:
    from markergraph.common.numbers import counted
    from markergraph.records import LINKING_METHODS

    extraction = result.extraction
    read = [s.extraction for s in result.sessions] or [extraction]  # every log's, not the first's
    markers = {o.marker_id for e in read for o in e.observations}
    several = f" in {len(read)} logs" if len(read) > 1 else ""
    print(
        f"{sum(e.frames for e in read)} frames{several}, "
        f"{sum(len(e.observations) for e in read)} observations of "
        f"{counted(len(markers), 'marker')}, home marker {result.frames.home_id}"
    )
    header = f"{'method':<14} {'markers':>7} {'links':>5}"
    if result.true_markers:
        # Aligned first: the figure evo and other mappers report; home-fixed carries the home
        # marker's own error to the far markers.
        header += (
            f" {'aligned RMSE [m]':>16} {'home-fixed RMSE [m]':>19} {'ATE aligned [m]':>15}"
            f" {'ATE home-fixed [m]':>18} {'poses':>6}"
        )
    print(header)
    for method_result in result.results:
        estimate = method_result.estimate
        links = len(estimate.links) if method_result.method in LINKING_METHODS else "-"
        line = f"{method_result.label:<14} {len(estimate.markers):>7} {links:>5}"
        if method_result.map_error is not None:
            line += _error_columns(method_result, method_result.map_error)
        print(line)
        for estimate_note in estimate.notes:
            print(f"  {method_result.label}: {estimate_note.text}")
    if any(r.method not in LINKING_METHODS for r in result.results):
        print("  links: marker pairs measured together; - for the EKF, which ties its markers "
              "through its covariance alone")  # fmt: skip
    for method_result in result.results:
        judgement = method_result.judgement
        print(f"verdict {method_result.label}: {judgement.verdict.value}", end="")
        print("".join(f"\n  - {reason.text}" for reason in judgement.reasons))
    for reason, count in sorted(extraction.skipped.items()):
        print(f"  {counted(count, 'frame')}: {reason}")
    for n, session in enumerate(result.sessions, start=1):
        where = "in the map" if session.trajectory is not None else "shares no marker: mapped apart"
        print(f"log {n}: {session.log} ({session.extraction.frames} frames), {where}")
    for n, (logs, marker_map) in enumerate(result.separate, start=1):
        print(
            f"separate map {n}: {len(marker_map.markers)} markers from {', '.join(map(str, logs))}"
        )
    say_notes([*result.notes, *extraction.warnings], quiet=quiet)
