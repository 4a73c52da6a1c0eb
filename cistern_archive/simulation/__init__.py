"""Generators of sites and scans with known truth, for tests, benchmarks and demonstrations.

- :mod:`~cistern_archive.simulation.spec` and :mod:`~cistern_archive.simulation.simulator`: the
  physical sonar simulator (beam cone, speckle, ghosts, compass noise) over a site spec;
  :mod:`~cistern_archive.simulation.output` writes a simulated site as a catalog record with its truth.
- :mod:`~cistern_archive.simulation.stations` and :mod:`~cistern_archive.simulation.gallery`: station
  routes and gallery outlines.
- :mod:`~cistern_archive.simulation.chambers`: random multi-chamber cisterns joined by tunnels.
- :mod:`~cistern_archive.simulation.pairs` and :mod:`~cistern_archive.simulation.rays`: scan pairs with
  a known displacement (ideal rays or the physical simulator), for the matcher benchmark and the
  plugin conformance kit.
- :mod:`~cistern_archive.simulation.synthetic`: small synthetic catalogs for the service's tests.

Nothing in the product's pipeline imports this package; the simulator-driven commands (``simulate``,
``emulate``) and the test kit do.
"""
