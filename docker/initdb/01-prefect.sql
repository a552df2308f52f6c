-- The Prefect server keeps its own database next to photoshape's metadata database.
CREATE DATABASE prefect OWNER photoshape;
