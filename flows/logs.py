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

PROJECT_LOGGER = "photoshape_flow"


def forward_project_logs(level: int = logging.INFO) -> logging.Logger:
    """Attach Prefect's API log handler to the project's logger (idempotent); INFO and up by default."""
    from prefect.logging.handlers import APILogHandler

    logger = logging.getLogger(PROJECT_LOGGER)
    if not any(isinstance(h, APILogHandler) for h in logger.handlers):
        configured = [h for h in logging.getLogger("prefect.extra").handlers if isinstance(h, APILogHandler)]
        logger.addHandler(configured[0] if configured else APILogHandler())
    if logger.level == logging.NOTSET or logger.level > level:
        logger.setLevel(level)
    return logger
