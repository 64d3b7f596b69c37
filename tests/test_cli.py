"""The mi-nest command line: render with -D, EXR channels by name, PNG preview, errors."""
import re
import numpy as np

from mi_nest.cli import main
from mi_nest.io.exr import read_channels
from mi_nest.physics import MEASUREMENTS


def test_render_writes_named_channels_and_preview(tmp_path, capsys):
    exr, png = tmp_path / "disk.exr", tmp_path / "disk.png"
    code = main(["render", "disk_compression", "-o", str(exr), "-D", "res=24", "-D", "spp=1",
                 "--png", str(png), "--quiet"])
    assert code == 0
    assert f"wrote {exr}" in capsys.readouterr().out
    channels = read_channels(exr)
    expected = {"Y", "jones.a", "jones.b", "jones.c", "jones.d", "char.delta", "char.theta", "char.gamma",
                "fringe.order", "path.length", *MEASUREMENTS}
    assert set(channels) == expected
    assert channels["Y"].shape == (24, 24)
    # Unit quaternions everywhere, whatever order the file stored the channels in.
    norm = sum(channels[f"jones.{c}"] ** 2 for c in "abcd")
    np.testing.assert_allclose(norm, 1.0, atol=1e-5)
    # The scene's main channel is the dark-field circular polariscope: sin^2(delta/2).
    np.testing.assert_allclose(channels["Y"], np.sin(channels["char.delta"] / 2) ** 2, atol=1e-2)
    assert png.stat().st_size > 500


def test_render_reports_errors_with_exit_code(tmp_path, capsys):
    assert main(["render", str(tmp_path / "missing.xml"), "-o", str(tmp_path / "x.exr")]) == 2
    assert "scene file not found" in capsys.readouterr().err
    assert main(["render", "disk_compression", "-o", str(tmp_path / "x.exr"), "-D", "nonsense=1"]) == 2
    assert "nonsense" in capsys.readouterr().err


def test_demo_runs_the_whole_loop_and_prints_where_it_wrote(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path), "--iterations", "20"]) == 0
    out = capsys.readouterr().out
    assert str(tmp_path / "disk_compression.exr") in out and "fringe order at the centre 6.006" in out
    assert re.search(r"relative deviatoric stress error: \d+\.\d%", out)
    for name in ("disk_compression.png", "truth.exr", "reconstructed.exr", "truth_vs_reconstructed.png",
                 "dataset/dataset.json", "reconstruction/field.npz", "reconstruction/test_view.png"):
        assert (tmp_path / name).exists(), name
