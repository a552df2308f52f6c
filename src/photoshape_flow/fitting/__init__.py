"""Stage 8, fit: each observed part's material chosen by rendering the pair against its photo.

The database-facing steps (context, candidates and lighting per pair, refinement, the fit weights'
calibration, rows and claims); `fit_stage` is the registry's entry. The science is `fit/` (pure),
named apart so that a reader sees which side of the database a module is on.
"""
