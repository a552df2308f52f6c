"""Pipeline stages: select pending items, call the science, write blobs then rows, record failures.

No Prefect here: the flows in `photoshape_flow.flows` and the CLI (`photoshape run`) both call these.
"""
