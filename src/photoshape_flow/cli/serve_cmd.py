"""`photoshape serve`: serve the deployments of prefect.yaml against a Prefect server."""

from __future__ import annotations

from pathlib import Path

import typer

from photoshape_flow.cli.common import console, fail


def serve(
    names: list[str] = typer.Argument(None, help="Deployments to serve (default: all in prefect.yaml)."),
    limit: int | None = typer.Option(None, help="Maximum concurrent flow runs of this server process."),
    list_only: bool = typer.Option(False, "--list", help="Print the deployments and exit."),
    write_yaml: bool = typer.Option(False, "--write-yaml", help="Rewrite prefect.yaml's stage deployments from "
                                    "the stage registry and exit."),
    declarations: Path | None = typer.Option(None, "--declarations", help="Serve the deployments of this "
                                             "prefect.yaml instead of the project's (e.g. with other schedules)."),
    keep_schedules: bool = typer.Option(False, "--keep-schedules", help="On stopping, leave the deployments "
                                        "as they were (default: pause them all, nightly included, until the "
                                        "next serve)."),
) -> None:
    """Serve every deployment of prefect.yaml (schedules, the material-added trigger) until Ctrl-C.

    Stopping pauses every deployment served, nightly included, until the next `photoshape serve`
    un-pauses them; --keep-schedules leaves them active (the server keeps scheduling their runs, which
    wait for a serving process).

    Needs a Prefect server: `prefect server start` (SQLite) or with
    PREFECT_SERVER_DATABASE_CONNECTION_URL=postgresql+asyncpg://..., and PREFECT_API_URL pointing at it.
    """
    from photoshape_flow.config import get_settings
    from photoshape_flow.flows.deployments import build_deployments, load_declarations, write_stage_deployments
    from photoshape_flow.flows.deployments import serve as serve_deployments

    if write_yaml:
        changed = write_stage_deployments()
        console.print("prefect.yaml: stage deployments " + ("rewritten" if changed else "already up to date"))
        return
    if list_only:
        for spec in load_declarations(declarations):
            if not names or spec["name"] in names:
                console.print(f"{spec['name']:18} {spec['entrypoint']}", highlight=False)
        return
    if not get_settings().effective_prefect_api_url:
        fail("no Prefect API configured: start `prefect server start` and export "
             "PREFECT_API_URL=http://127.0.0.1:4200/api")
    if declarations is not None and not declarations.is_file():
        fail(f"{declarations}: no such file")
    deployments = build_deployments(declarations, names=names or None)
    console.print(f"serving {len(deployments)} deployments: {', '.join(d.name for d in deployments)}")
    console.print("stopping (Ctrl-C) " + ("leaves their schedules as they are" if keep_schedules else
                  "pauses them all, nightly included, until the next `photoshape serve` (--keep-schedules: "
                  "leave them active)"), highlight=False, soft_wrap=True)
    serve_deployments(names or None, limit=limit, path=declarations, keep_schedules=keep_schedules)


def register(app: typer.Typer) -> None:
    app.command("serve")(serve)
