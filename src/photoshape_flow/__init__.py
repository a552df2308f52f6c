"""photoshape_flow: photorealistic, relightable materials for 3D shape collections.

A re-implementation of PhotoShape (Park et al., SIGGRAPH Asia 2018) as a workflow-orchestrated
data platform: a SQL metadata database, a content-addressed blob store, pure science packages
and Prefect flows around them.
"""

__version__ = "0.1.0"
