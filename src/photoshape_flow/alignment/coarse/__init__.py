"""The pieces of the coarse alignment stage; `alignment.coarse_alignment` composes them into the stage.

- `config`: `CoarseConfig`, the stage's parameters (its hashes are stored with the rows).
- `viewpoint_sets`: the immutable `ViewpointSet` rows and the feature hashes that depend on them.
- `features`: steps 1 and 2, the descriptor shards of shapes' viewpoint sweeps and of exemplars.
- `reverse_index`: the stored per-exemplar top-k lists (`ExemplarMatch` rows), read and rewritten.
- `pairs`: step 3, the incremental search that updates the reverse index and the `Pair` rows.
- `evaluation`: recall, pose error and silhouette IoU of the reverse index against ground truth.
"""
