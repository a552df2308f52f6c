"""The project's log lines in the Prefect UI.

Prefect forwards only its own run loggers to the API; the pipeline logs through
`logging.getLogger("photoshape_flow...")`. `forward_project_logs` gives the project's logger the
handlers Prefect keeps for extra loggers (its API log handler), as `PREFECT_LOGGING_EXTRA_LOGGERS`
would, but in code, so it holds in every process that runs a flow or a task (served subprocesses,
work-pool workers, Dask workers) whatever their environment. Only flows and tasks call it: the CLI
runs outside any flow run, where the handler has nothing to attach a line to. Records are masked by the password
filter `photoshape_flow.masking` installs on every record, so a database URL never reaches the UI.
"""

from __future__ import annotations

import logging

from photoshape_flow.masking import PasswordMaskFilter

PROJECT_LOGGER = "photoshape_flow"


def _in_a_run(record: logging.LogRecord) -> bool:
    """Only records made inside a flow or task run go to the API (the same process may also run CLI code,
    e.g. a test or a notebook, where Prefect's handler would warn about a missing flow run id)."""
    from prefect.context import FlowRunContext, TaskRunContext

    return FlowRunContext.get() is not None or TaskRunContext.get() is not None


def forward_project_logs(level: int = logging.INFO) -> logging.Logger:
    """Attach Prefect's API log handler to the project's logger (idempotent); INFO and up by default."""
    from prefect.logging.handlers import APILogHandler

    logger = logging.getLogger(PROJECT_LOGGER)
    if not any(isinstance(h, APILogHandler) for h in logger.handlers):
        handler = APILogHandler()
        handler.addFilter(_in_a_run)
        handler.addFilter(PasswordMaskFilter())
        logger.addHandler(handler)
    if logger.level == logging.NOTSET or logger.level > level:
        logger.setLevel(level)
    return logger
