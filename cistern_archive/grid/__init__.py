"""Evidence grids: the inverse sonar model, a tiled sparse store, ray casting, exports.

Modules
-------
evidence
    Log-odds inverse sonar model over the beam cone (:class:`SonarModel`, :func:`scan_window`,
    :func:`dense_scan_map`).
tiles
    :class:`TiledGrid`, a dictionary of fixed-size tiles allocated on touch.
raycast
    Distance fields, brute-force ray marching and sphere tracing over boolean occupancy.
export
    Deterministic PNG and ``.npz`` writers for :class:`~cistern_archive.pipeline.contracts.EvidenceGrid`.
polygon
    Range scans ray cast inside a polygon (known geometry for tests and benchmarks).
volume
    Depth slices resampled onto one lattice (:func:`common_lattice`, :func:`resample`) and interpolated
    in depth.
surface
    The wall surface from the evidence (:func:`wall_surface`): the water the vehicle saw, bounded where
    walls were seen; the pipeline's mesh step.
"""
