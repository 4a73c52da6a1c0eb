"""Live acquisition from a Tritech Micron over a serial line, and the sonar-head emulator.

- :mod:`~.driver`: the head's start-up, parameter and data exchange (``mtSendVersion`` →
  ``mtHeadCommand`` → ``mtSendData``); :mod:`~.assembly`: its lines assembled into a 360° scan.
- :mod:`~cistern_archive.acquisition.session`: one station's capture into a catalog (raw stream first,
  then the scan and the record), safe against a pulled cable or a Ctrl-C.
- :mod:`~cistern_archive.acquisition.emulator` (the head), :mod:`~.emulator_server` (the wire),
  :mod:`~.echoes` and :mod:`~.faults`: a sonar head on a pseudo-terminal that answers like a
  Micron with echoes from the simulator, for tests and for rehearsing a dive.
"""
