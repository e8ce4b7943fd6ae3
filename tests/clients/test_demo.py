"""``mrdem demo`` against a running service: CSV, PNG and a ParaView time series."""

from __future__ import annotations

import numpy as np

from clients import demo
from mrdem_common.serving import readyz


def test_demo_writes_csv_png_and_vtk(live_service, tmp_path, capsys):
    assert demo.main(["--url", live_service.url, "--steps", "200", "--out", str(tmp_path)]) == 0
    rows = np.genfromtxt(tmp_path / "particle_on_plane.csv", delimiter=",", names=True)
    assert len(rows) == 200 and rows["time"][-1] == np.float64(0.2)
    assert rows["contacts"].max() > 0 and rows["converged"].all()  # it landed
    assert (tmp_path / "particle_on_plane.png").stat().st_size > 10_000
    frames = sorted((tmp_path / "vtk").glob("frame_*.vtk"))
    assert len(frames) == 20
    first = frames[0].read_text().splitlines()
    assert first[0] == "# vtk DataFile Version 3.0" and first[3] == "DATASET POLYDATA"
    assert "POINTS 646 double" in first  # 642 sphere vertices + 4 plane corners
    pvd = (tmp_path / "vtk" / "particle_on_plane.pvd").read_text()
    assert pvd.count("<DataSet ") == 20
    assert "lowest gap" in capsys.readouterr().out


def test_without_url_the_demo_starts_a_service_and_stops_it():
    with demo.local_service() as url:
        assert readyz(url)
    assert not readyz(url)  # stopped, its temporary store gone with it
