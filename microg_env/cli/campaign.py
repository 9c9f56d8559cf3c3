"""The ``microg campaign`` command: a campaign file's runs on Ray, stored as they finish."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from microg_env.cli.common import check_writable_folder, progress_bar

#: Where a campaign's folder goes by default: ``results/campaigns/<name>``.
DEFAULT_CAMPAIGN_ROOT = "results/campaigns"


def _cmd_campaign(args: argparse.Namespace) -> int:
    from microg_env.experiments.campaign import Campaign
    from microg_env.experiments.distributed import check_address, check_folder

    if args.address is not None:
        if not args.address.strip():
            raise ValueError(
                "--address: the address is empty (give HOST:PORT, 'auto', or leave it out for a local Ray)"
            )
        try:
            check_address(args.address)  # before Ray is imported: it reads its settings once
        except ConnectionError as error:
            raise ValueError(f"--address {args.address!r}: {error}") from None
    try:
        import ray  # noqa: F401
    except ImportError:
        raise ValueError("microg campaign needs the campaign extra: pip install 'microg-env[campaign]'") from None
    from microg_env.experiments.distributed import execute

    campaign = Campaign.load(args.spec)
    out = args.out if args.out is not None else str(Path(DEFAULT_CAMPAIGN_ROOT) / campaign.name)
    if not out.strip():
        raise ValueError("--out: the folder name is empty")
    if Path(out).exists() and not Path(out).is_dir():
        raise ValueError(f"--out {out!r} exists and is not a folder")
    check_writable_folder(out, "--out")
    if args.num_cpus is not None and args.num_cpus < 1:
        raise ValueError(f"--num-cpus must be at least 1, got {args.num_cpus}")
    check_folder(campaign, Path(out))
    with progress_bar(f"campaign {campaign.name}", args.quiet, unit="run") as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done)

        try:
            summary = execute(campaign, out, args.address, args.num_cpus, progress)
        except KeyboardInterrupt:
            bar.close()
            print(
                f"microg campaign: interrupted; every finished run is stored in {out} (run the same command to resume)",
                file=sys.stderr,
            )
            return 130
        except ConnectionError as error:
            raise ValueError(f"--address {args.address!r}: {error}") from None
    if args.json:
        print(json.dumps(summary.as_dict(), indent=2))
    else:
        print(
            f"campaign {summary.name}: {summary.runs} runs; {summary.done} run now, {summary.failed} failed, "
            f"{summary.skipped} already stored ({summary.wall_s:.0f} s)"
        )
        print(f"wrote {summary.results}" + (f" and {summary.report}" if summary.report else ""))
    return 0


def add_commands(commands) -> None:
    """campaign."""
    campaign = commands.add_parser(
        "campaign",
        help="run a campaign file (grid, Monte Carlo draws, seeds) on Ray; results to Parquet",
        description="Expand a YAML campaign (a base run spec, a sweep: grid of parameters, samples: drawn from "
        "distributions, seeds:) into runs and run them on Ray: a local instance on this machine's cores, or a "
        "cluster with --address. One row per run goes to DIR/runs/ as runs finish; re-running the same command "
        "skips the runs this microg version already stored; a run that raises is stored with its error. "
        "DIR/results.parquet is the campaign's table; a campaign with report: writes DIR/report.md and its figures.",
    )
    campaign.add_argument("spec", metavar="SPEC.yml", help="the campaign file (studies/ holds examples)")
    campaign.add_argument(
        "--out", metavar="DIR", help=f"results folder (default {DEFAULT_CAMPAIGN_ROOT}/NAME); kept and added to"
    )
    campaign.add_argument(
        "--address", metavar="RAY_ADDRESS", help="an existing Ray cluster (HOST:PORT or 'auto'); default: a local Ray"
    )
    campaign.add_argument(
        "--num-cpus",
        type=int,
        metavar="N",
        help="CPUs of the local Ray (default: every usable core; ignored with --address)",
    )
    campaign.add_argument("--json", action="store_true", help="print a JSON summary")
    campaign.add_argument("--quiet", action="store_true", help="no progress bar")
    campaign.set_defaults(handler=_cmd_campaign)
