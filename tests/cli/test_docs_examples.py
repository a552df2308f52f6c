"""The docs check: every `photoshape ...` line of a shell block in the README and docs is a command the CLI
accepts, every verb has one, and every verb's example runs: here (on a tiny published collection, or the
tiny demo itself) or in the test named for it in `RUN_ELSEWHERE`, which must still invoke that verb.

Parsing goes through click's own parser (`make_context`), so a renamed option, a verb that moved, an
argument of the wrong type or a missing one fails here, before a reader copies it."""

from __future__ import annotations

import ast
import re
import shlex
from functools import cache
from pathlib import Path

import pytest
import sqlalchemy as sa
import typer
from tests.conftest import REPO_ROOT
from typer.testing import CliRunner

from photoshape_flow.cli import app

DOCS = (REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md")),
        REPO_ROOT / "experiments" / "second_world" / "README.md")
# pair ids the README's examples name; the runs below give them the seeded pair's id
EXAMPLE_PAIRS = ("42", "57")
# verbs (or verb + option) whose examples run in another test: where, as "path::function"
RUN_ELSEWHERE: dict[str, str] = {
    "ingest": "tests/pipeline/test_ingest_cli.py::test_ingest_commands",
    "run": "tests/pipeline/test_publish.py::test_gallery_opens_on_published_photoshapes_and_publishes_on_demand",
    "run all": "tests/pipeline/whole_runs.py::run_all",  # the reference collection of tests/conftest.py
    "new-materials": "tests/pipeline/test_material_fit_first.py::"
                     "test_a_new_material_wins_parts_through_fit_without_a_retrain",
    "eval": "tests/cli/test_eval_groundtruth.py::test_eval_groundtruth_scores_the_good_entries_and_names_each_bad_one",
    "retrieve": "tests/pipeline/test_training.py::test_retrieve_cli_ranks_materials_for_a_region",
    "serve": "tests/flows/test_server.py::test_serve_registers_the_deployments_and_debounces_material_events",
    "doctor": "tests/cli/test_foundation_cli.py::test_doctor_reports_each_check",
    "gallery --serve": "tests/cli/test_gallery_serve.py::test_serve_writes_a_grade_and_stops_on_ctrl_c",
}
# verbs whose documented examples `test_documented_examples_run` runs as written
RUN_HERE = ("db", "status", "claims", "gallery", "export", "grade", "gc")


def shell_lines(text: str) -> list[str]:
    """The lines inside ```bash fences."""
    lines, inside = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            inside = not inside and line.strip() in ("```bash", "```sh", "```shell")
        elif inside:
            lines.append(line)
    return lines


@cache
def documented_commands() -> tuple[tuple[str, tuple[str, ...]], ...]:
    """(document, argv after `photoshape`) of every command line in a shell block of the docs."""
    found = []
    for doc in DOCS:
        for line in shell_lines(doc.read_text()):
            for part in re.split(r"&&|;", line.split(" #")[0]):
                if part.split()[:1] == ["photoshape"]:
                    found.append((doc.relative_to(REPO_ROOT).as_posix(), tuple(shlex.split(part)[1:])))
    return tuple(found)


def verb_of(argv: tuple[str, ...]) -> str:
    """The name RUN_ELSEWHERE/RUN_HERE use for a command: its verb, or verb + the option that makes it
    another use (`gallery --serve`, `run all`)."""
    if argv[0] == "gallery" and "--serve" in argv:
        return "gallery --serve"
    if argv[:2] == ("run", "all"):
        return "run all"
    return argv[0]


class Unparsed(Exception):
    """A documented command the CLI would refuse, with click's message."""


def parse(argv: tuple[str, ...]) -> None:
    """Parse `photoshape argv` as the CLI would, without running it; `Unparsed` says what is wrong.

    Typer vendors click (typer._click), so this walks its public types: TyperGroup down to the verb,
    then the verb's own `make_context` (types, choices, required arguments and options)."""
    command = typer.main.get_command(app)
    ctx = typer.Context(command, info_name="photoshape")
    args = list(argv)
    while isinstance(command, typer.core.TyperGroup):
        if not args:
            raise Unparsed(f"{ctx.info_name}: a verb is missing")
        name, args = args[0], args[1:]
        sub = command.get_command(ctx, name)
        if sub is None:
            raise Unparsed(f"no such verb: {name}")
        command, ctx = sub, typer.Context(sub, info_name=name, parent=ctx)
    try:
        command.make_context(ctx.info_name, args, parent=ctx.parent)
    except typer.exceptions.TyperException as exc:  # click's UsageError and BadParameter, vendored
        message = exc.format_message() if hasattr(exc, "format_message") else str(exc)
        raise Unparsed(f"{ctx.info_name}: {message}") from None


def test_the_docs_have_shell_examples() -> None:
    docs = {doc for doc, _ in documented_commands()}
    assert {"README.md", "docs/operations.md", "docs/evaluation.md"} <= docs
    assert len(documented_commands()) >= 30


def test_documented_commands_parse() -> None:
    wrong = []
    for doc, argv in documented_commands():
        try:
            parse(argv)
        except Unparsed as exc:
            wrong.append(f"{doc}: photoshape {shlex.join(argv)}: {exc}")
    assert wrong == []


def test_parse_catches_what_is_wrong() -> None:
    """The check itself: a wrong option, verb, argument type or a missing argument is reported."""
    for argv in (("gallery", "out/", "--serv"), ("grades", "1", "good"), ("grade", "one", "good"), ("grade",),
                 ("export",), ("ingest", "shape", "x/")):
        with pytest.raises(Unparsed):
            parse(argv)
    parse(("grade", "1", "good", "--note", "fine"))


def _invokes(target: str, verb: str) -> bool:
    """Whether the function `target` ("path::name") exists and names every word of `verb` as a string
    (how the tests pass a command line to the CLI)."""
    path, name = target.split("::")
    tree = ast.parse((REPO_ROOT / path).read_text())
    function = next((node for node in ast.walk(tree) if isinstance(node, ast.FunctionDef) and node.name == name), None)
    if function is None:
        return False
    strings = {node.value for node in ast.walk(function)
               if isinstance(node, ast.Constant) and isinstance(node.value, str)}
    return all(word in strings for word in verb.split())


def test_every_verb_has_an_example_that_runs() -> None:
    verbs = set(typer.main.get_command(app).commands)  # what `photoshape --help` lists
    assert sorted(verbs - {argv[0] for _, argv in documented_commands()}) == []
    documented = {verb_of(argv) for _, argv in documented_commands()}
    assert "gallery --serve" in documented
    runs = set(RUN_HERE) | set(RUN_ELSEWHERE) | {"demo"}  # demo: test_the_tiny_demo_runs_as_documented
    assert sorted(documented - runs) == []
    assert [target for verb, target in RUN_ELSEWHERE.items() if not _invokes(target, verb)] == []


@pytest.fixture
def published(db_url, store, tmp_path):  # type: ignore[no-untyped-def]
    """test_publish's seed, both pairs publishable and published, with classifier rows as well as fit's."""
    from tests.pipeline.test_publish import seed

    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.publish.publish import run_publish

    ids = seed(db_url, store, tmp_path)
    with session_scope(db_url) as session:
        oak, missing = (session.execute(sa.select(m.Material).where(m.Material.name == name)).scalar_one()
                        for name in ("oak_01", "missing_03"))
        missing.maps = dict(oak.maps)
        for row in session.execute(sa.select(m.Assignment).where(m.Assignment.method == "fit")).scalars().all():
            session.add(m.Assignment(pair_id=row.pair_id, part_id=row.part_id, method="classifier",
                                     classifier_id=row.classifier_id, method_key=f"classifier:{row.classifier_id}",
                                     rank=row.rank, material_id=row.material_id, score=row.score,
                                     substance=row.substance))
    assert run_publish(views=1, size=16, spp=2, formats=("glb", "xml", "obj")).failed == 0
    return ids


@pytest.mark.render
def test_documented_examples_run(published, db_url, tmp_path, monkeypatch):  # type: ignore[no-untyped-def]
    """Each example of a RUN_HERE verb, as written (pair ids excepted), on a tiny published collection."""
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    ran = []
    for doc, argv in documented_commands():
        if verb_of(argv) not in RUN_HERE:
            continue
        args = [str(published["good"]) if word in EXAMPLE_PAIRS else word for word in argv]
        result = runner.invoke(app, args)
        assert result.exit_code == 0, f"{doc}: photoshape {shlex.join(argv)}\n{result.output}"
        ran.append(verb_of(argv))
    assert set(ran) == set(RUN_HERE)
    assert (tmp_path / "out" / "index.html").is_file() and (tmp_path / "out" / "sheet.png").is_file()
    assert {p.name for p in (tmp_path / "exports").iterdir()} == {f"{published[k]}-fit-{published['classifier']}"
                                                                 for k in ("good", "broken")}
    assert any((tmp_path / "exports-cls").iterdir())
    with sa.create_engine(db_url).connect() as conn:
        assert conn.execute(sa.text("SELECT pair_id, label FROM grade")).all() == [(published["good"], "wrong_color")]


@pytest.mark.slow
@pytest.mark.render
def test_the_tiny_demo_runs_as_documented(settings_env, monkeypatch):  # type: ignore[no-untyped-def]
    """docs/operations.md's `photoshape demo --size tiny --no-evaluate`, as a user runs it: exit 0, a gallery
    and a short log. The one test that runs the demo verb itself (160 s on 2 busy cores): the kill-point
    tests' reference collection is built with `run all`, under other ingest sources, so it cannot stand in."""
    import os
    import subprocess
    import sys

    argv = next(argv for _, argv in documented_commands() if argv[:1] == ("demo",))
    env = {**os.environ, "PHOTOSHAPE_SEED": "3", "PHOTOSHAPE_TORCH_THREADS": "1"}
    done = subprocess.run([str(Path(sys.executable).with_name("photoshape")), *argv], env=env, capture_output=True,
                          text=True, timeout=1200)
    log = done.stdout + done.stderr
    assert done.returncode == 0, log[-3000:]
    # about 65 lines (one per loop, a warning or two, the stage table); the small demo's must stay under 200
    assert len(log.splitlines()) < 120, log
    assert (settings_env / "gallery" / "index.html").is_file()
