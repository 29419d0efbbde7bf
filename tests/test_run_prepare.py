"""``ogiflow run --prepare``: the simulated scene rendered and the solvers compiled before a
first start, nothing opened or recorded (what tools/install.sh runs)."""

from __future__ import annotations

from appliance import cli


def test_prepare_renders_the_configured_scene_and_records_nothing(tmp_path, capsys) -> None:
    cache, rec = tmp_path / "cache", tmp_path / "recordings"
    small = ["--set", f"simulation.cache_dir={cache}", "--set", "simulation.frames=10",
             "--set", "simulation.voxel_m=0.06", "--record-dir", str(rec)]
    assert cli.main(["run", "--prepare", *small]) == cli.EXIT_OK
    out = capsys.readouterr().out
    assert "ogiflow: ready: simulated scene cached in" in out
    assert "the chain's kernels compiled" in out
    scenes = list(cache.glob("field-*/meta.json"))
    assert len(scenes) == 1  # the configured scene itself, not a preview beside it
    assert not rec.exists()  # no recorder, no device, no live view
    # A second call finds it cached.
    assert cli.main(["run", "--prepare", *small]) == cli.EXIT_OK
    assert list(cache.glob("field-*/meta.json")) == scenes


def test_prepare_checks_the_configuration_first(tmp_path, capsys) -> None:
    assert cli.main(["run", "--prepare", "--set", "simulation.frames=1",
                     "--set", f"simulation.cache_dir={tmp_path}"]) == cli.EXIT_USAGE
    assert "simulation.frames" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
