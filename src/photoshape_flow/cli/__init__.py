"""The `photoshape` command line: one module per verb, each with a `register(app)` function.

Verb modules import heavy libraries (Mitsuba, torch, Prefect) inside their commands so that
`photoshape --help` stays fast.
"""

from __future__ import annotations

import importlib
import importlib.util

import typer

app = typer.Typer(
    name="photoshape",
    help="Photorealistic, relightable materials for 3D shape collections (PhotoShape, SIGGRAPH Asia 2018).",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_show_locals=False,
)

# Order is the order of `photoshape --help`.
VERB_MODULES: tuple[str, ...] = (
    "demo", "ingest", "run", "new_materials", "status", "claims", "eval", "export", "gallery", "retrieve", "grade",
    "serve", "db", "doctor", "gc",
)


def package_version() -> str:
    """The installed distribution's version (what `photoshape --version` prints)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("photoshape_flow")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "unknown (not installed)"


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"photoshape_flow {package_version()}")
        raise typer.Exit()


def _require_blob_backend() -> None:
    """One line naming the package to install when the blob store's URL needs a missing fsspec backend.

    Checked before any verb runs, so an ``s3://`` root without s3fs is that line (exit 1), not an
    ImportError traceback from wherever the store is first opened. `doctor` reports it itself.
    """
    try:
        from photoshape_flow.config import get_settings

        root = get_settings().blob_root
    except Exception:  # broken settings: the verb reports them in its own words
        return
    from photoshape_flow.store.refs import is_url

    if not is_url(root):
        return
    from photoshape_flow.store.remote import missing_backend

    reason = missing_backend(str(root))
    if reason is not None:
        from photoshape_flow.cli.common import fail

        fail(reason)


@app.callback()
def _options(
    ctx: typer.Context,
    version: bool = typer.Option(False, "--version", help="Print the version and exit.", is_eager=True,
                                 callback=_show_version),
) -> None:
    """Photorealistic, relightable materials for 3D shape collections (PhotoShape, SIGGRAPH Asia 2018)."""
    if ctx.invoked_subcommand not in (None, "doctor") and not ctx.resilient_parsing:
        _require_blob_backend()


def _register_verbs() -> None:
    for name in VERB_MODULES:
        module_name = f"{__name__}.{name}_cmd"
        if importlib.util.find_spec(module_name) is None:
            continue
        importlib.import_module(module_name).register(app)


_register_verbs()


def main() -> None:
    app()
