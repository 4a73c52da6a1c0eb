"""A junk file is refused from its head, before the nightly rebuild archives it, in every format."""

import pytest

from cistern_archive.core.errors import ReaderError
from cistern_archive.sonar.readers import check_file

JUNK = b"\x00junk" * 2000


@pytest.mark.parametrize("name, fmt", [
    ("scan.npz", "npz"), ("log.v4log", "seanet-v4log"), ("capture.seanet", "seanet-raw"),
    ("UdpHubLog_4001.csv", "seanet-udphub"), ("rev.pcd", "marina-pcd"), ("log.bin", "ping360"),
])
def test_junk_is_refused_from_the_header(tmp_path, name, fmt):
    path = tmp_path / name
    path.write_bytes(JUNK)
    with pytest.raises(ReaderError) as err:
        check_file(path, fmt)
    assert str(path) in str(err.value)


@pytest.mark.realdata
def test_the_real_recordings_pass_their_header_check(shared_data):
    files = [p for p in shared_data.rglob("*") if p.is_file() and p.suffix.lower() in (".v4log", ".csv", ".pcd")]
    if not files:
        pytest.skip(f"no SeaNet or marina recordings under {shared_data}")
    for path in files[:20]:
        if path.suffix.lower() == ".csv" and not path.name.startswith("UdpHubLog"):
            continue
        check_file(path)
