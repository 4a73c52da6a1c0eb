"""Live acquisition from a Tritech Micron over a serial line, and the sonar-head emulator.

- :mod:`~cistern_archive.acquisition.driver`: the head's start-up, parameter and data exchange
  (``mtSendVersion`` → ``mtHeadCommand`` → ``mtSendData``), assembling beams into a 360° scan.
- :mod:`~cistern_archive.acquisition.session`: one station's capture into a catalog (raw stream first,
  then the scan and the record), safe against a pulled cable or a Ctrl-C.
- :mod:`~cistern_archive.acquisition.emulator`: a sonar head on a pseudo-terminal that answers like a
  Micron with echoes from the simulator, for tests and for rehearsing a dive.
"""
