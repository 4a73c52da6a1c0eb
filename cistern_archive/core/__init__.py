"""The bottom layer: plain types and file I/O that every other layer may use and that import nothing above.

- :mod:`~cistern_archive.core.errors` and :mod:`~cistern_archive.core.exitcodes`: the error types a user
  sees (each names the file, record or packet) and the command line's exit codes.
- :mod:`~cistern_archive.core.files`: the one atomic writer.
- :mod:`~cistern_archive.core.scan`: the scan model (raw beams and segmented ranges).
- :mod:`~cistern_archive.core.matches`, :mod:`~cistern_archive.core.poses`,
  :mod:`~cistern_archive.core.grids`, :mod:`~cistern_archive.core.dimensions`: what each pipeline stage
  returns (the stages' protocols are in :mod:`cistern_archive.pipeline.contracts`).
"""
