"""``cistern-archive emulate``: a software Micron DST head on a pseudo-terminal or a TCP port.

The first line printed is what ``cistern-archive acquire --port`` (or ``serial.serial_for_url``) opens:
the pty's path, or ``socket://127.0.0.1:PORT``. The head then serves until interrupted (Ctrl-C or SIGTERM).
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Optional

import typer

from cistern_archive.commands import EXIT_OK, EXIT_USAGE


def register(app: typer.Typer) -> None:
    @app.command("emulate")
    def emulate(
        catalog: Path = typer.Option(Path("catalog"), "--catalog", help="Catalog root."),
        site: str = typer.Option(..., "--site", help="Id of a simulated site whose walls the head echoes."),
        station: Optional[str] = typer.Option(None, "--station",
                                              help="Station of the site's spec (default: the first)."),
        tcp: Optional[int] = typer.Option(None, "--tcp", help="Serve on this TCP port of 127.0.0.1 instead of a pty "
                                "(0 picks a free port)."),
        host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on with --tcp."),
        faults: str = typer.Option("", "--faults", help="e.g. 'drop=0.001,flip=0.001,garbage=0.02,stall=150,"
                                   "stall_s=2,reboot=300,seed=7' (rates per byte/packet, counts in scan lines)."),
        half_duplex: bool = typer.Option(False, "--half-duplex", help="One scan line per mtSendData (default two)."),
        fast: bool = typer.Option(False, "--fast", help="Answer at once instead of at the acoustic/serial pace."),
        alive_s: float = typer.Option(1.0, "--alive-period", min=0.05, help="mtAlive period, seconds."),
        boot_s: float = typer.Option(1.5, "--boot", min=0.0, help="Silence after a reboot, seconds."),
    ) -> None:
        """Emulate a Micron DST head echoing a catalog site's simulated walls; prints the port URL first."""
        from cistern_archive.core.errors import CatalogError  # deferred
        from cistern_archive.acquisition.emulator import HeadTiming
        from cistern_archive.acquisition.emulator_server import build_emulator
        from cistern_archive.acquisition.faults import FaultPlan
        from cistern_archive.acquisition.echoes import SimulatedEcho

        try:
            plan = FaultPlan.parse(faults)
            echo = SimulatedEcho.from_catalog(catalog, site, station)
            server = build_emulator(echo, faults=plan, tcp_port=tcp, host=host, half_duplex=half_duplex,
                                    timing=HeadTiming(alive_period=alive_s, boot=boot_s, realtime=not fast))
        except (CatalogError, ValueError, OSError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        sys.stdout.write(server.url + "\n")
        sys.stdout.flush()
        typer.echo(f"emulating site {site!r} station {echo.pose.station!r}; faults: {faults or 'none'}; "
                   "Ctrl-C stops", err=True)

        def _terminate(signum: int, frame: object) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, _terminate)
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            server.stop()
        typer.echo(f"stopped after {server.head.lines_sent} scan lines, {server.bytes_out} bytes sent", err=True)
        raise typer.Exit(EXIT_OK)
