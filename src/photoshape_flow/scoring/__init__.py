"""After the stages, scoring: every stage against a ground-truth file (`photoshape eval`), stored as
`evaluation` rows. The file format, bootstrap and tables are `evaluation/` (pure).
"""
