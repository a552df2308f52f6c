"""Progress of long loops: the plain lines off a terminal, and the `photoshape run` summary table."""

from __future__ import annotations

import re

import pytest
from tests.pipeline.test_publish import seed

from photoshape_flow.cli.progress import PlainProgress
from photoshape_flow.progress_sink import counted, labelled, nested, progress_line


def test_plain_lines_one_per_loop_at_its_end_and_at_most_every_ten_seconds_while_it_runs():
    lines: list[str] = []
    now = [0.0]
    sink = PlainProgress(lines.append, clock=lambda: now[0])
    for _ in counted(sink, "publish pairs", range(40)):
        now[0] += 0.5  # 2 items/s: 20 s in all
    assert lines == ["publish pairs: 20/40 (50%), 2.00/s, ETA 0:10",  # 10 s in: the one running line
                     "publish pairs: 40/40 (100%), 2.00/s, took 0:20"]
    fast: list[str] = []
    sink = PlainProgress(fast.append, clock=lambda: now[0])
    for _ in counted(sink, "inference pairs", range(10)):
        now[0] += 0.01  # 100 items/s: one line, at its end
    assert [line.split(",")[0] for line in fast] == ["inference pairs: 10/10 (100%)"]
    slow: list[str] = []
    sink = PlainProgress(slow.append, clock=lambda: now[0])
    sink("training epochs", 0, 1000)
    now[0] += 11.0  # few items, but 10 s passed
    sink("training epochs", 3, 1000)
    now[0] += 1.0
    sink("training epochs", 4, 1000)  # within 10 s of the last line: quiet
    assert len(slow) == 1 and slow[0].startswith("training epochs: 3/1000 (0%)") and slow[0].endswith("ETA 1:00:56")
    assert progress_line("ingest shapes", 0, 0, 0.0) == "ingest shapes: 0"


def test_batches_are_one_loop_and_a_batch_prints_only_when_it_runs_long():
    """What the stage runner reports for a stage in batches (`stages.run._fan_out_here`): the batch loop,
    each batch's loops nested in it and named by stage and batch."""
    lines: list[str] = []
    now = [0.0]
    sink = PlainProgress(lines.append, clock=lambda: now[0])
    for k, _ in enumerate(counted(sink, "training-renders batches", range(20)), start=1):
        batch = nested(sink, f"training-renders batch {k}/20")
        for _ in counted(batch, "training renders", range(16)):
            now[0] += 0.25 if k != 7 else 1.0  # 4 s a batch; batch 7 takes 16 s
    # quick batches say nothing; the batch loop prints every 10 s at most; batch 7 ran long: its own lines
    assert [line.split(" (")[0] for line in lines] == [
        "training-renders batches: 3/20", "training-renders batches: 6/20",
        "training-renders batch 7/20: training renders: 10/16", "training-renders batch 7/20: training renders: 16/16",
        "training-renders batches: 10/20", "training-renders batches: 13/20", "training-renders batches: 16/20",
        "training-renders batches: 19/20", "training-renders batches: 20/20"]
    assert lines[-1].endswith("took 1:32")
    labelled_lines: list[str] = []
    plain = labelled(PlainProgress(labelled_lines.append, clock=lambda: now[0]), "substances")
    for _ in counted(plain, "bootstrap renders", range(2)):
        pass
    for _ in counted(plain, "substances network epochs", range(1)):
        pass
    assert [line.split(" (")[0] for line in labelled_lines] == ["substances: bootstrap renders: 2/2",
                                                                "substances network epochs: 1/1"]


@pytest.mark.render
def test_run_publish_off_a_terminal_prints_one_line_per_loop_a_plain_summary_and_where_it_wrote(
        db_url, store, tmp_path):
    """Through the real CLI (CliRunner's stdout is no terminal): one line per loop (the quick batches
    inside the batch loop say nothing), a table of counts, then where the gallery and exports are."""
    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.config import get_settings
    from photoshape_flow.stages.registry import get_stage

    seed(db_url, store, tmp_path)
    object.__setattr__(get_stage("publish"), "batch_size", 1)  # two pairs: two batches
    try:
        small = ["--set", "publish.views=0", "--set", "publish.size=16", "--set", "publish.spp=2",
                 "--set", "publish.formats=glb"]
        result = CliRunner().invoke(app, ["run", "publish", *small])
    finally:
        object.__setattr__(get_stage("publish"), "batch_size", 8)
    assert result.exit_code == 0, result.output
    progress = [line for line in result.output.splitlines() if "%)" in line]
    assert [line.split(" (")[0] for line in progress] == ["publish batches: 2/2", "publish: gallery candidates: 2/2"]
    assert re.search(r"publish batches: 2/2 \(100%\), [\d.]+/s, took \d+:\d\d", result.output), result.output
    table = result.output[result.output.index("stages run"):]
    row = next(line for line in table.splitlines() if line.lstrip("│┃ ").startswith("publish"))
    cells = [c.strip() for c in re.split(r"[│┃]", row) if c.strip()]
    assert cells[0] == "publish" and all(c.replace(".", "").isdigit() for c in cells[1:]), cells
    assert "{" not in table
    data_root = get_settings().data_root
    assert f"gallery:  {data_root / 'gallery' / 'index.html'}" in result.output
    assert f"exports:  {data_root / 'exports'}" in result.output
    assert (data_root / "gallery" / "index.html").is_file()


def test_a_terminal_gets_rich_bars_and_a_pipe_plain_lines():
    import io

    from rich.console import Console

    from photoshape_flow.cli.progress import RichProgress, cli_progress

    terminal = Console(file=io.StringIO(), force_terminal=True, width=100)
    with cli_progress(terminal) as sink:
        assert isinstance(sink, RichProgress)
        for _ in counted(sink, "publish pairs", range(3)):
            pass
        assert sink.bar.tasks[0].completed == 3 and sink.bar.tasks[0].total == 3
    pipe = Console(file=io.StringIO(), force_terminal=False)
    with cli_progress(pipe) as sink:
        assert isinstance(sink, PlainProgress)
        sink("export pairs", 0, 2)
        sink("export pairs", 2, 2)
    assert pipe.file.getvalue().startswith("export pairs: 2/2 (100%)")
    assert pipe.file.getvalue().count("\n") == 1
