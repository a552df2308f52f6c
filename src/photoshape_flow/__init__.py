"""photoshape_flow: photorealistic, relightable materials for 3D shape collections.

A re-implementation of PhotoShape (Park et al., SIGGRAPH Asia 2018) as a workflow-orchestrated
data platform: a SQL metadata database, a content-addressed blob store, pure science packages
and Prefect flows around them.
"""

__version__ = "0.1.0"

# Every process that runs this package (CLI, Prefect worker, Dask worker) masks database passwords
# in every log record before any handler, Prefect's API log handler included, sees it.
from photoshape_flow.masking import install_password_masking

install_password_masking()
