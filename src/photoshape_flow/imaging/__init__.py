"""Image handling for ingest: defensive decoding, exemplar cleaning (mask, square crop), dense-HOG
duplicate search, SVBRDF material folders and HDR environment maps. No database, no Prefect."""
