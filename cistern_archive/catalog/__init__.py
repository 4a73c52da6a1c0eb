"""Site catalog: pydantic records and YAML loading with line numbers.

Validating a record against the installed plugins is the pipeline's job (:mod:`cistern_archive.pipeline.validate`).
"""
