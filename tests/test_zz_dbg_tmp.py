from pathlib import Path
from cistern_archive.service.rebuild import rebuild
from service_helpers import FAST_REPORT, make_catalog

def test_x(tmp_path):
    cat = make_catalog(tmp_path / "catalog")
    s = rebuild(cat, tmp_path / "out", workers=2, report_config=FAST_REPORT)
    for x in s.sites:
        print(x.id, x.status, x.error, x.detail[-2500:])
    assert 0
