"""The echoes an emulated head sends: the walls around one station through the sonar simulator."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cistern_archive.acquisition.session import find_site
from cistern_archive.core.errors import CatalogError
from cistern_archive.simulation.simulator import TruePose, simulate_scan, station_poses
from cistern_archive.simulation.spec import EffectsSpec, SonarSpec, load_spec
from cistern_archive.sonar.geometry import Slice, interpolate_slice
from cistern_archive.tritech.codec import DEFAULT_SPEED_OF_SOUND, STEPS_PER_REV
from cistern_archive.tritech.head_command import HeadCommand

__all__ = ["SimulatedEcho"]

TYPICAL_IGAIN, TYPICAL_AD_LOW, TYPICAL_AD_SPAN = 84, 8, 81
"""The gain, ADLow and ADSpan (§7.4 units) at which the simulator's echo levels hold unchanged."""

@dataclass(frozen=True, eq=False)
class SimulatedEcho:
    """The walls around one station and the sonar model that turns them into scan lines.

    Attributes
    ----------
    rings : list of (K, 2) arrays
        The walls at the station's depth, map frame.
    pose : TruePose
        The station (position, yaw, depth).
    sonar : SonarSpec
        Physical sonar model; range, bins and step are replaced by the head's configuration.
    effects : EffectsSpec
        Imperfections (speckle, ghosts, spikes...).
    water_depth_m : float, optional
        Floor depth, for floor reverberation.
    """

    rings: Slice
    pose: TruePose
    sonar: SonarSpec = field(default_factory=SonarSpec)
    effects: EffectsSpec = field(default_factory=EffectsSpec)
    water_depth_m: float | None = None

    @classmethod
    def from_polygon(cls, vertices: np.ndarray, *, x_m: float, y_m: float, yaw_deg: float = 0.0,
                     depth_m: float = 1.0, effects: EffectsSpec | None = None) -> "SimulatedEcho":
        """A station at (x, y) with heading ``yaw_deg`` (map frame, CCW from east) inside one polygon."""
        pose = TruePose("emulated", float(x_m), float(y_m), math.radians(yaw_deg), float(depth_m))
        return cls([np.asarray(vertices, dtype=np.float64)], pose,
                   effects=EffectsSpec() if effects is None else effects)

    @classmethod
    def from_catalog(cls, catalog: str | os.PathLike, site_id: str, station: str | None = None) -> "SimulatedEcho":
        """The simulated geometry of a catalog site, seen from one of its stations.

        Parameters
        ----------
        catalog : path
            Catalog root (records in it or in ``sites/``).
        site_id : str
            Record id; the record must name its simulator spec (``simulation:``).
        station : str, optional
            Station label of the spec; the first station when omitted.

        Raises
        ------
        CatalogError
            Unknown site, a site without a simulation spec, or an unknown station.
        """
        root = Path(catalog)
        loaded = find_site(root, site_id)
        if loaded.record.simulation is None:
            raise CatalogError([f"{loaded.path}: site {site_id!r} has no 'simulation' spec; the emulator echoes "
                                "simulated sites only"])
        spec = load_spec(loaded.resolve(loaded.record.simulation))
        poses = station_poses(spec)
        chosen = poses[0] if station is None else next((p for p in poses if p.station == station), None)
        if chosen is None:
            raise CatalogError([f"{loaded.path}: site {site_id!r} has no station {station!r}; "
                                f"stations: {', '.join(p.station for p in poses)}"])
        rings = interpolate_slice(spec.site.slices(), chosen.depth_m)
        return cls(rings, chosen, spec.sonar, spec.effects, spec.site.water_depth_m)

    def revolution(self, cmd: HeadCommand, rng: np.random.Generator,
                   speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> np.ndarray:
        """Intensities (0..255) of one revolution for the head's settings.

        Row ``k`` is the beam ``k x step`` clockwise from ahead (bearing ``3200 + k x step``), as
        :func:`~cistern_archive.simulation.simulator.beam_bearings` orders them.

        The spec's AD window is taken as the head's at the typical command (IGain 84, ADLow 8, ADSpan 81,
        §12.3); the command's departures from it move the window: ``+80/210 dB`` per IGain unit lowers the
        floor, ADLow and ADSpan shift and scale it at ``80/255 dB`` per unit (§7.4).
        """
        step = max(1, cmd.step_size)
        n_bins = max(1, cmd.n_bins)
        gain_db = (cmd.igain[0] - TYPICAL_IGAIN) * 80.0 / 210.0
        low_db = self.sonar.ad_low_db + (cmd.ad_low - TYPICAL_AD_LOW) * 80.0 / 255.0 - gain_db
        span_db = max(self.sonar.ad_span_db + (cmd.ad_span - TYPICAL_AD_SPAN) * 80.0 / 255.0, 1.0)
        sonar = self.sonar.model_copy(update={
            "range_m": max(n_bins * cmd.bin_size_m(speed_of_sound), 0.01),
            "bins": n_bins,
            "step_deg": step * 360.0 / STEPS_PER_REV,
            "ad_low_db": low_db,
            "ad_span_db": span_db,
        })
        simulated = simulate_scan(self.rings, self.pose, sonar, self.effects, rng, water_depth_m=self.water_depth_m)
        return np.asarray(simulated.scan.intensities)
