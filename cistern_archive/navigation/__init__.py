"""Navigation of a moving sonar vehicle: dead reckoning, clock alignment, motion compensation.

* :mod:`.track` — :class:`~.track.Track`, a dead-reckoned SE(2) trajectory with covariance, and
  :func:`~.track.dead_reckon` (body-frame bottom velocity + heading);
* :mod:`.survey` — the Girona marina survey: navigation logs, per-beam sonar times, key frames;
* :mod:`.motion` — motion compensation of every echo to its scan's reference time;
* :mod:`.clock` — the offset between the sonar and navigation clocks, estimated from the scans;
* :mod:`.accuracy` — errors of a track against DGPS fixes, start-aligned and after rigid alignment.
"""
