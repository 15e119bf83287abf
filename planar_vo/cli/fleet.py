"""``planar_vo fleet``: replay and evaluate many bags, times a grid of configurations, on Ray.

``run`` starts one Ray task per bag and configuration (``planar_vo replay`` and, when the bag
has ground truth on /ground_truth/odom, ``planar_vo eval --align sim3``: the same result, to the
last bit), on a local Ray instance started for the run (``--workers`` CPUs) or on an existing
cluster (``--address``). DIR gets per bag and configuration the odometry bag, a TUM file and
the metrics, then summary.json (one row per bag and configuration), report.md and plots.
Rerunning the same command skips what is complete in DIR; Ctrl-C stops cleanly.

Needs Ray (pip install 'planar_vo[fleet]'), except with --local: the jobs then run in this
process, one after the other, with the same results.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from planar_vo.cli import Once

log = logging.getLogger('planar_vo')

EXAMPLES = """examples:
  planar_vo fleet run drives/*.mcap --out fleet_out               one task per bag, all CPUs
  planar_vo fleet run --manifest bags.txt --out fleet_out --workers 2
  planar_vo fleet run kitti/* --out sweep --set voting.bins=360,720 --set keyframe.min_parallax=2,4
  ray start --head && planar_vo fleet run --manifest bags.txt --out fleet_out --address auto
  planar_vo fleet run --manifest bags.txt --out fleet_out --address ray://head:10001
  planar_vo fleet run drives/*.mcap --out fleet_out --local         no Ray, one bag at a time
With a cluster, the bags and DIR must be on a file system every node sees.
"""


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'fleet', help='replay and evaluate many bags (x configurations) on Ray',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    actions = parser.add_subparsers(dest='fleet_action', metavar='ACTION', required=True)
    run_parser = actions.add_parser(
        'run', help='run a fleet of bags', description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    run_parser.add_argument('bags', nargs='*', metavar='BAG',
                            help='input bags (directory, .mcap or .db3)')
    run_parser.add_argument('--out', required=True, metavar='DIR',
                            help='output folder (complete results already in it are reused)')
    run_parser.add_argument('--manifest', metavar='FILE',
                            help='text file of bag paths, one a line (# comments; relative '
                                 'paths are relative to the file)')
    run_parser.add_argument('--config', metavar='YAML', action=Once,
                            help='configuration file (default: built-in defaults)')
    run_parser.add_argument('--set', action='append', default=[], metavar='KEY=V1[,V2...]',
                            help='configuration values by dotted key (voting.bins=360,720); '
                                 'several values, or several --set, run every combination')
    run_parser.add_argument('--address', metavar='ADDR',
                            help="an existing Ray cluster: 'auto', 'ray://host:10001' or "
                                 "'host:6379' (default: a local instance for this run)")
    run_parser.add_argument('--workers', type=int, metavar='N',
                            help='CPUs of the local instance, one task per CPU (default: all '
                                 'this process may use)')
    run_parser.add_argument('--retries', type=int, metavar='N',
                            help='reruns of a task whose worker died (killed, out of memory) '
                                 '(default: 2)')
    run_parser.add_argument('--local', action='store_true',
                            help='run in this process, one bag after the other, without Ray '
                                 '(the same results; no --address, --workers, --retries)')
    run_parser.add_argument('--image-topic', metavar='TOPIC',
                            help="every bag's image topic, as replay's (default: the only one)")
    run_parser.add_argument('--camera-info-topic', metavar='TOPIC',
                            help="every bag's CameraInfo topic, as replay's (default: the only "
                                 'one, if any)')
    run_parser.add_argument('--two-pass', action='store_true',
                            help="as replay's: with camera.estimate_focal, a first pass over "
                                 'each bag self-calibrates the focal length that the odometry '
                                 'uses from its first frame on')
    run_parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    run_parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from planar_vo.cli import print_final, show_progress
    from planar_vo.config import read_config
    from planar_vo.errors import InputError
    from planar_vo.tools.fleet import (
        config_grid,
        plan_jobs,
        read_manifest,
        run_fleet,
    )

    if args.local:
        given = [f'--{n}' for n in ('address', 'workers', 'retries')
                 if getattr(args, n) is not None]
        if given:
            raise InputError(f'{given[0]}: --local runs in this process, without Ray')
    if args.address and args.workers is not None:
        raise InputError('--workers: --workers sizes the local Ray instance; with --address the '
                         "cluster's CPUs are used")
    if args.workers is not None and args.workers < 1:
        raise InputError(f'--workers: expected at least 1, got {args.workers}')
    retries = 2 if args.retries is None else args.retries
    if retries < 0:
        raise InputError(f'--retries: expected 0 or more, got {args.retries}')
    bags = list(args.bags) + (read_manifest(args.manifest) if args.manifest else [])
    if not bags:
        raise InputError('BAG: expected BAG arguments or --manifest FILE, got none')
    typed = [str(bag) for bag in args.bags if not Path(bag).expanduser().exists()]
    if typed:
        # A path typed on the command line that does not exist is a typo (a user test: it
        # became a failed row of a run that exited 0); a manifest's missing bags are rows.
        raise InputError(f"BAG: '{typed[0]}' does not exist" + (
            f' (and {len(typed) - 1} more of the bags given)' if len(typed) > 1 else ''))
    missing = [str(bag) for bag in bags if not Path(bag).expanduser().exists()]
    if len(missing) == len(bags):
        # Found before Ray starts; with some bags present the missing ones are failed rows.
        raise InputError(f"BAG: '{missing[0]}' does not exist" if len(missing) == 1 else
                         f"BAG: none of the {len(missing)} bags exists ('{missing[0]}', ...)")
    file_values = read_config(args.config)
    configs = config_grid(file_values, args.set, source=args.config)
    if 'mount.height' not in file_values and not any(
            item.partition('=')[0].strip() == 'mount.height' for item in args.set):
        # As replay's summary says it (a user test: KITTI ran at the default without a word).
        log.warning("mount.height: the default %g m sets every metric scale; give the car's "
                    '(--set mount.height=M, or in --config)', configs[0].values['mount.height'])
    speed = [c.name for c in configs if c.values['scale.source'] == 'speed']
    if speed:
        # A fleet run feeds no speed topic: every step would be a fallback (as replay refuses
        # scale.source: speed without --speed-topic).
        raise InputError(f'scale.source: speed needs a speed topic, which fleet run does not '
                         f"feed (configuration '{speed[0]}'); use planar_vo replay "
                         f'--speed-topic per bag, or another scale.source')
    command = ['planar_vo', 'fleet', 'run', *args.bags, '--out', args.out]
    for flag in ('manifest', 'config', 'address', 'workers', 'retries', 'image_topic',
                 'camera_info_topic'):
        if getattr(args, flag) is not None:
            command += [f'--{flag.replace("_", "-")}', str(getattr(args, flag))]
    if args.local:
        command.append('--local')
    if args.two_pass:
        command.append('--two-pass')
    for item in args.set:
        command += ['--set', item]
    jobs = plan_jobs(bags, configs, image_topic=args.image_topic,
                     camera_info_topic=args.camera_info_topic, two_pass=args.two_pass)
    result = run_fleet(jobs, args.out, address=args.address, workers=args.workers,
                       retries=retries, progress=show_progress(args), command=command,
                       local=args.local)
    print_final(result.format())        # (the summary and report are written by now)
    if result.interrupted:
        # The line every command ends an interruption with (a user test: only stdout said it;
        # and SIGTERM returned Ctrl-C's code).
        print(f'{args.parser.prog}: interrupted by {result.stop_signal.name}; kept '
              f'{len(result.rows)} of {result.jobs} results in {args.out} (rerun the same '
              f'command to finish)', file=sys.stderr)
        return 128 + result.stop_signal.value
    if result.rows and all(row['status'] == 'failed' for row in result.rows):
        # Nothing usable came out (every row names its reason above): a script must see it.
        print(f'{args.parser.prog}: error: all {len(result.rows)} runs failed', file=sys.stderr)
        return 1
    return 0
