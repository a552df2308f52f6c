"""Evaluation without a database: the ground-truth file format (`groundtruth`) and the headline
tables (`tables`). Pure like the science packages, so the demo generator can write and read the
format; `scoring.groundtruth_match` and `scoring.evaluate` bring in the database."""
