"""`photoshape demo`: generate the built-in demo collections and run the whole pipeline on them."""

from __future__ import annotations

import time
from enum import StrEnum

import typer

from photoshape_flow.cli.common import console, fail, setup_logging, shown_database_url
from photoshape_flow.cli.progress import cli_progress


class DemoSize(StrEnum):
    tiny = "tiny"
    small = "small"
    medium = "medium"


def demo(
    size: DemoSize = typer.Option(DemoSize.small, help="tiny (seconds, CI) | small (minutes) | medium (accuracy)."),
    seed: int = typer.Option(None, help="Seed of the generated collections (default: PHOTOSHAPE_SEED)."),
    evaluate: bool = typer.Option(True, help="Score every stage against the ground truth at the end."),
    prefect: bool = typer.Option(False, help="Run the stages as the photoshape-pipeline Prefect flow."),
    wait: bool = typer.Option(False, "--wait", help="Wait for items another live worker holds (default: say so "
                              "and exit with code 3)."),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log each step."),
) -> None:
    """Generate procedural shapes, SVBRDFs, studio envmaps and photo-like exemplars, then run every stage."""
    from photoshape_flow.cli.eval_cmd import print_metrics, print_problem
    from photoshape_flow.cli.run_cmd import print_reports, run_reporting_blocked
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.demo import generate_demo
    from photoshape_flow.flows.events import stage_context
    from photoshape_flow.ingest.ingest_stage import COLLECTIONS, IngestRequest
    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.publish.publish_stage import gallery_dir
    from photoshape_flow.stages import STAGE_NAMES, run_all

    setup_logging(verbose)
    settings = get_settings()
    started = time.perf_counter()
    try:
        migrate.upgrade()
    except Exception as exc:
        fail(f"{shown_database_url()}: cannot migrate ({exc})")
    out_dir = settings.data_root / "demo" / size.value
    console.print(f"generating the {size.value} demo collections in {out_dir} ...", highlight=False)
    source = f"demo-{size.value}"
    manifest = generate_demo(out_dir, size.value, seed=settings.seed if seed is None else seed,
                             source=source)
    request = IngestRequest(
        roots={name: [manifest.root / name] for name in COLLECTIONS}, source=source, license="CC0-1.0",
        attribution=f"photoshape_flow demo generator (procedural, seed {manifest.seed})",
    )
    profile = resolve_profile(size.value)
    announce = lambda r: console.print(f"[green]done[/] {r.stage} ({r.seconds:.1f} s)")  # noqa: E731
    with cli_progress(console) as progress:
        ctx = stage_context(progress=progress)
        if prefect:
            from photoshape_flow.flows.pipeline import photoshape_pipeline

            reports = run_reporting_blocked(lambda: run_all(profile, ctx, names=["ingest"], ingest=request,
                                                            origin="demo", on_stage=announce, wait=wait))
            photoshape_pipeline(profile=size.value, stages=[s for s in STAGE_NAMES if s != "ingest"])
        else:
            reports = run_reporting_blocked(lambda: run_all(profile, ctx, ingest=request, origin="demo",
                                                            on_stage=announce, wait=wait))
    print_reports(reports)
    if evaluate:
        from photoshape_flow.scoring.evaluate import run_evaluation

        with cli_progress(console) as progress:
            run_name, metrics = run_evaluation(manifest.groundtruth, f"{source}-{time.strftime('%Y%m%d-%H%M%S')}",
                                               exemplar_source=source, on_problem=print_problem, progress=progress)
        print_metrics(metrics, run_name)
        console.print(f"evaluation stored as run [bold]{run_name}[/] (table `evaluation`)")
    elapsed = time.perf_counter() - started
    console.print(f"\n[bold]demo finished in {elapsed / 60:.1f} min[/]")
    console.print(f"  gallery:  {gallery_dir(ctx) / 'index.html'}", highlight=False)
    console.print(f"  exports:  {settings.data_root / 'exports'}", highlight=False)
    console.print(f"  database: {shown_database_url()}  (try `photoshape status`, or the SQL view "
                  "photoshape_candidate)", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)
