"""What every stage package shares: the stage contract and the rows every stage reads or writes.

`context.StageContext`, `report.StageReport`, `work.WorkUnit` (the contract of a stage module),
`runs` (pipeline_run records and the profile a collection last ran with), `progress` (the registry's
counters), `renderings` and `render_inputs` (rendering rows, material and envmap specs from rows),
`errors` (one-line failure reasons) and `gc` (unreferenced blobs). The stages themselves live in
their domain packages (`ingest/` ... `scoring/`), above this one. No Prefect here.
"""
