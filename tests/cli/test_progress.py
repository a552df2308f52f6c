"""Progress of long loops: the plain lines off a terminal, and the `photoshape run` summary table."""

from __future__ import annotations

import re

import pytest
from tests.pipeline.test_publish import seed

from photoshape_flow.cli.progress import PlainProgress
from photoshape_flow.progress_sink import counted, progress_line


def test_plain_lines_every_tenth_and_every_ten_seconds_with_rate_and_eta():
    lines: list[str] = []
    now = [0.0]
    sink = PlainProgress(lines.append, clock=lambda: now[0])
    for _ in counted(sink, "publish pairs", range(40)):
        now[0] += 0.5  # 2 items/s
    assert lines[0] == "publish pairs: 0/40 (0%)"
    assert lines[1] == "publish pairs: 1/40 (2%), 2.00/s, ETA 0:20"  # the first item: the first ETA
    assert lines[2] == "publish pairs: 4/40 (10%), 2.00/s, ETA 0:18"
    assert lines[-1] == "publish pairs: 40/40 (100%), 2.00/s, took 0:20"
    assert len(lines) == 12  # the start, the first item, then every 4 items (a tenth)
    fast: list[str] = []
    sink = PlainProgress(fast.append, clock=lambda: now[0])
    for _ in counted(sink, "inference pairs", range(10)):
        now[0] += 0.01  # 100 items/s: a line per tenth would be noise
    assert [line.split(",")[0] for line in fast] == [
        "inference pairs: 0/10 (0%)", "inference pairs: 1/10 (10%)", "inference pairs: 10/10 (100%)"]
    slow: list[str] = []
    sink = PlainProgress(slow.append, clock=lambda: now[0])
    sink("training epochs", 0, 1000)
    now[0] += 11.0  # fewer items than a tenth, but 10 s passed
    sink("training epochs", 3, 1000)
    assert slow[-1].startswith("training epochs: 3/1000 (0%)") and slow[-1].endswith("ETA 1:00:56")
    assert progress_line("ingest shapes", 0, 0, 0.0) == "ingest shapes: 0"


@pytest.mark.render
def test_run_publish_off_a_terminal_prints_counts_eta_and_a_plain_summary(db_url, store, tmp_path):
    """Through the real CLI (CliRunner's stdout is no terminal): count/ETA lines, then a table of counts."""
    from typer.testing import CliRunner

    from photoshape_flow.cli import app

    seed(db_url, store, tmp_path)
    small = ["--set", "publish.views=0", "--set", "publish.size=16", "--set", "publish.spp=2",
             "--set", "publish.formats=glb"]
    result = CliRunner().invoke(app, ["run", "publish", *small])
    assert result.exit_code == 0, result.output
    assert "publish pairs: 0/2 (0%)" in result.output
    assert re.search(r"publish pairs: 1/2 \(50%\), [\d.]+/s, ETA \d+:\d\d", result.output), result.output
    assert re.search(r"publish pairs: 2/2 \(100%\), [\d.]+/s, took", result.output), result.output
    table = result.output[result.output.index("stages run"):]
    row = next(line for line in table.splitlines() if line.lstrip("│┃ ").startswith("publish"))
    cells = [c.strip() for c in re.split(r"[│┃]", row) if c.strip()]
    assert cells[0] == "publish" and all(c.replace(".", "").isdigit() for c in cells[1:]), cells
    assert "{" not in table


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
    assert pipe.file.getvalue() == "export pairs: 0/2 (0%)\n"
