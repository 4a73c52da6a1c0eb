"""Reliability of the archive and the nightly rebuild under faults: the fault-injection suites, counted.

Runs ``tests/test_faults*.py`` (slow cases included) under pytest with ``$CISTERN_RELIABILITY_LOG`` set:
each fault case that guards data snapshots the raw inputs and published reports before its fault and
writes, after the fault and the recovery, how many files or reports were lost. The table counts, per
suite, the cases tried (tests run, not skipped), the faults survived (tests passed: no traceback reached
the user, every good site built, ``verify`` passed after the repair, nothing lost) and the data lost
(files or reports, summed over the guarded cases; must be 0).

Usage::

    python benchmarks/reliability.py            # a Markdown table
    python benchmarks/reliability.py --json
    python benchmarks/reliability.py --fixity-cost 60 --json

``--fixity-cost N`` measures instead what checking every stored copy costs a no-change rebuild: the
second (unchanged) ingest of every record and scan of ``N`` generated sites, which re-hashes each
archived object it relies on (three passes).

Needs root for the full- and read-only-disk cases (a small tmpfs is mounted); without it they are
skipped and not counted as tried.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SUITES = ("tests/test_faults.py", "tests/test_faults_archive.py", "tests/test_faults_input.py",
          "tests/test_faults_kill.py")


def run_suites(work: Path) -> tuple[ET.Element, list[dict]]:
    """Run every fault suite once; return the JUnit XML report and the data-loss records."""
    junit, losses = work / "junit.xml", work / "losses.jsonl"
    env = {**os.environ, "CISTERN_RELIABILITY_LOG": str(losses)}
    subprocess.run([sys.executable, "-m", "pytest", *SUITES, "-m", "", "-q", "-p", "no:cacheprovider",
                    f"--junitxml={junit}"], cwd=REPO, env=env, check=False, stdout=sys.stderr)
    records = [json.loads(line) for line in losses.read_text().splitlines()] if losses.is_file() else []
    return ET.parse(junit).getroot(), records


def tally(root: ET.Element, records: list[dict]) -> dict[str, dict[str, int]]:
    """Per suite: cases tried, survived, guarded (with a data-loss check) and files or reports lost."""
    rows: dict[str, dict[str, int]] = defaultdict(lambda: {"tried": 0, "survived": 0, "guarded": 0, "lost": 0})
    for case in root.iter("testcase"):
        suite = case.get("classname", "").split(".")[-1]
        if case.find("skipped") is not None:
            continue
        rows[suite]["tried"] += 1
        if case.find("failure") is None and case.find("error") is None:
            rows[suite]["survived"] += 1
    for record in records:
        suite = Path(record["case"].split("::")[0]).stem
        rows[suite]["guarded"] += 1
        rows[suite]["lost"] += record["lost"]
    return dict(sorted(rows.items()))


def fixity_cost(n_sites: int, work: Path) -> dict:
    """Seconds of an unchanged ingest of every input of ``n_sites`` generated sites (objects re-hashed)."""
    import time

    from cistern_archive.archive import Archive
    from cistern_archive.pipeline.validate import validate_catalog
    from cistern_archive.service.planning import site_inputs
    from cistern_archive.simulation.synthetic import write_synthetic_catalog

    catalog = work / "catalog"
    write_synthetic_catalog(catalog, n_sites, seed=2024)
    records = validate_catalog(catalog).records
    files = [(r.path, r.record.id) for r in records]
    files += [(r.resolve(relative), r.record.id) for r in records for _, relative in site_inputs(r)]
    passes = []
    with Archive(work / "archive") as archive:
        for path, site in files:
            archive.ingest(path, site_id=site)
        for _ in range(3):
            start = time.perf_counter()
            for path, site in files:
                archive.ingest(path, site_id=site)
            passes.append(round(time.perf_counter() - start, 3))
    return {"sites": n_sites, "files": len(files), "bytes": sum(p.stat().st_size for p, _ in files),
            "unchanged_ingest_s": passes}


def markdown(rows: dict[str, dict[str, int]]) -> str:
    lines = ["| suite | cases tried | faults survived | with a data-loss check | data lost (files or reports) |",
             "|---|---|---|---|---|"]
    total = {"tried": 0, "survived": 0, "guarded": 0, "lost": 0}
    for suite, row in rows.items():
        lines.append(f"| `{suite}` | {row['tried']} | {row['survived']} | {row['guarded']} | {row['lost']} |")
        total = {k: total[k] + row[k] for k in total}
    lines.append(f"| **all** | **{total['tried']}** | **{total['survived']}** | **{total['guarded']}** | "
                 f"**{total['lost']}** |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print JSON instead of a Markdown table")
    parser.add_argument("--fixity-cost", type=int, metavar="SITES", default=None,
                        help="measure the cost of re-hashing archived objects in a no-change rebuild instead")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="cistern-reliability-") as work:
        if args.fixity_cost is not None:
            print(json.dumps(fixity_cost(args.fixity_cost, Path(work))))
            return
        rows = tally(*run_suites(Path(work)))
    print(json.dumps(rows, indent=2) if args.json else markdown(rows))


if __name__ == "__main__":
    main()
