"""Robustness matrices from YAML/JSON files: loading both parts, refusing wrong content."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from appliance import cli
from appliance.evaluation.matrix_file import MatrixFileError, load_matrix

DOC = {
    "name": "small",
    "n_frames": 4,
    "voxel_m": 0.12,
    "scenes": [{"seed": 7, "wind_m_s": [1.0, 0.0, 1.0], "distance_m": 4.5, "depth_m": 2.88}],
    "conditions": [{"name": "ideal"}, {"name": "jitter", "jitter_px": 0.3}],
    "holdout": {"scenes": [{"seed": 9, "wind_m_s": [-1, 0, 0], "release_rate_g_s": 2}]},
}


def _write(tmp_path: Path, doc: dict, suffix: str = ".json") -> Path:
    path = tmp_path / f"m{suffix}"
    if suffix == ".json":
        path.write_text(json.dumps(doc))
    else:
        import yaml

        path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_both_parts_load(tmp_path: Path, suffix: str) -> None:
    path = _write(tmp_path, DOC, suffix)
    dev = load_matrix(path)
    assert dev.name == "small" and dev.n_frames == 4 and dev.voxel_m == 0.12
    (scene,) = dev.scenes
    assert scene.wind_m_s == (1.0, 0.0, 1.0) and scene.distance_m == 4.5
    assert scene.depth_m == 2.88
    assert [c.name for c in dev.conditions] == ["ideal", "jitter"]
    assert dev.conditions[1].jitter_px == 0.3 and dev.conditions[1].realistic
    hold = load_matrix(path, "holdout")
    assert [s.seed for s in hold.scenes] == [9] and hold.scenes[0].release_rate_g_s == 2.0
    assert hold.conditions == dev.conditions  # the main part's unless it lists its own


def test_shipped_wide_matrix_is_valid_and_its_holdout_is_disjoint() -> None:
    path = Path(__file__).parent.parent / "benchmarks" / "matrices" / "wide.yaml"
    dev, hold = load_matrix(path), load_matrix(path, "holdout")
    assert {s.seed for s in dev.scenes}.isdisjoint({s.seed for s in hold.scenes})
    assert len(dev.scenes) >= 12 and len(hold.scenes) >= 8
    winds = [s.wind_m_s for s in dev.scenes]
    assert any(w[0] < 0 for w in winds) and any(w[0] > 0 for w in winds)
    assert any(w[1] < 0 for w in winds) and any(w[1] > 0 for w in winds)
    assert any(w[2] < 0 for w in winds) and any(w[2] > 0 for w in winds)
    assert len({s.distance_m for s in dev.scenes}) == 2
    assert len({s.release_rate_g_s for s in dev.scenes}) == 2


def test_the_reserves_share_no_scene_and_the_conditions_of_the_wide_matrix() -> None:
    """Each reserve hold-out is a check on scenes no setting saw: no seed of the wide
    matrix's parts or of the reserve before it, its five conditions exactly, in-plane and
    out-of-plane winds."""
    here = Path(__file__).parent.parent / "benchmarks" / "matrices"
    dev, hold = load_matrix(here / "wide.yaml"), load_matrix(here / "wide.yaml", "holdout")
    seen = {s.seed for s in (*dev.scenes, *hold.scenes)}
    for name in ("wide-reserve.yaml", "wide-second-reserve.yaml"):
        reserve = load_matrix(here / name)
        seeds = {s.seed for s in reserve.scenes}
        assert seeds.isdisjoint(seen), name
        assert len(reserve.scenes) == 8 and reserve.conditions == dev.conditions
        assert (reserve.n_frames, reserve.voxel_m) == (dev.n_frames, dev.voxel_m)
        assert any(s.wind_m_s[2] == 0 for s in reserve.scenes)
        assert any(s.wind_m_s[2] > 0 for s in reserve.scenes)
        assert any(s.wind_m_s[2] < 0 for s in reserve.scenes)
        seen |= seeds


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: d["scenes"][0].update(wind=[1, 0, 0]), "unknown key 'wind'.*wind_m_s"),
    (lambda d: d.update(scene=[]), "unknown key 'scene'"),
    (lambda d: d["conditions"][0].update(jiter_px=0.1), "did you mean 'jitter_px'"),
    (lambda d: d["scenes"][0].update(wind_m_s=[1, 0]), "three numbers"),
    (lambda d: d["conditions"][1].update(jitter_px="x"), "must be a number"),
    (lambda d: d["scenes"][0].update(distance_m=0.1), "within 1..100"),
    (lambda d: d["conditions"].append({"name": "ideal"}), "unique"),
    (lambda d: d["holdout"].update(scenes=d["scenes"]), "repeats development scenes"),
    (lambda d: d.pop("conditions"), "missing key 'conditions'"),
])
def test_wrong_content_is_named(tmp_path: Path, change, message: str) -> None:
    doc = json.loads(json.dumps(DOC))
    change(doc)
    with pytest.raises(MatrixFileError, match=message):
        load_matrix(_write(tmp_path, doc))


def test_cli_exits_2_on_a_wrong_key_and_a_missing_holdout(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = json.loads(json.dumps(DOC))
    doc["scenes"][0]["sede"] = 3
    path = _write(tmp_path, doc)
    assert cli.main(["eval", "robustness", "--matrix", str(path)]) == cli.EXIT_USAGE
    assert "unknown key 'sede'" in capsys.readouterr().err
    doc = json.loads(json.dumps(DOC))
    del doc["holdout"]
    path = _write(tmp_path, doc)
    assert cli.main(["eval", "robustness", "--matrix", str(path), "--part", "holdout"]) == \
        cli.EXIT_USAGE
    assert "no holdout section" in capsys.readouterr().err
    assert cli.main(["eval", "robustness", "--part", "holdout"]) == cli.EXIT_USAGE


def test_matrix_file_runs_with_a_configuration_files_parameters(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = json.loads(json.dumps(DOC))
    doc["scenes"][0] = {"seed": 7, "wind_m_s": [1.0, 0.0, 0.0]}
    doc["conditions"] = [{"name": "jitter", "jitter_px": 0.3}]
    path = _write(tmp_path, doc)
    site = tmp_path / "site.yaml"
    site.write_text("processing:\n  parameters: {register: false}\n")
    out = tmp_path / "r.json"
    args = ["eval", "robustness", "--matrix", str(path), "--cache-dir", str(tmp_path / "c"),
            "--json", str(out)]
    assert cli.main([*args, "--config", str(site)]) == cli.EXIT_OK
    assert "ogiflow run --config" in capsys.readouterr().out
    # registration off as the file says: the jitter is never corrected
    assert json.loads(out.read_text())["jitter"]["flags"].get("jitter_corrected", 0) == 0
    assert cli.main(args) == cli.EXIT_OK  # the default chain registers
    assert json.loads(out.read_text())["jitter"]["flags"].get("jitter_corrected", 0) >= 1


def test_a_condition_places_the_moving_object(tmp_path: Path) -> None:
    from appliance.evaluation import robustness as rb

    doc = json.loads(json.dumps(DOC))
    doc["conditions"] = [{"name": "far object", "moving_object": True, "object_z_m": 11.0},
                         {"name": "object", "moving_object": True}]
    m = load_matrix(_write(tmp_path, doc))
    base = rb.scene_config(m.scenes[0], m)
    far, near = (rb.condition_config(base, c).options.moving_object for c in m.conditions)
    assert far.z_m == 11.0 and near.z_m == rb.WARM_OBJECT.z_m == 8.0


def test_combined_matrix_runs_the_wide_scenes_under_its_disturbances_together() -> None:
    """wide-combined.yaml: the wide matrix's scenes, both parts, under two or three of its
    realistic disturbances at once, each with the single condition's own parameter."""
    here = Path(__file__).parent.parent / "benchmarks" / "matrices"
    wide = {part: load_matrix(here / "wide.yaml", part) for part in ("dev", "holdout")}
    combined = {part: load_matrix(here / "wide-combined.yaml", part)
                for part in ("dev", "holdout")}
    for part in ("dev", "holdout"):
        assert combined[part].scenes == wide[part].scenes
        assert (combined[part].n_frames, combined[part].voxel_m) == (
            wide[part].n_frames, wide[part].voxel_m)
    single = {c.name: c for c in wide["dev"].conditions}
    noise, jitter = single["noise 0.03 K"].noise_netd_k, single["jitter 0.3 px"].jitter_px
    assert noise > 0 and jitter > 0 and single["moving object"].moving_object
    disturbances = []
    for c in combined["dev"].conditions:
        on = {"noise": c.noise_netd_k == noise, "jitter": c.jitter_px == jitter,
              "object": c.moving_object}
        assert c.noise_netd_k in (0, noise) and c.jitter_px in (0, jitter)
        assert c.name == "+".join(k for k, v in on.items() if v) and sum(on.values()) >= 2
        assert c.realistic
        disturbances.append(frozenset(k for k, v in on.items() if v))
    assert len(set(disturbances)) == 4  # the three pairs and all three


def test_the_long_matrix_runs_wide_scenes_longer_part_by_part() -> None:
    """wide-long.yaml: development scenes of the wide matrix, unchanged, over more frames,
    in and out of the image plane, under the wide matrix's conditions; its hold-out part
    the wide matrix's hold-out scenes the same way."""
    here = Path(__file__).parent.parent / "benchmarks" / "matrices"
    wide = here / "wide.yaml"
    for part in ("dev", "holdout"):
        short, long = load_matrix(wide, part), load_matrix(here / "wide-long.yaml", part)
        assert set(long.scenes) <= set(short.scenes) and len(long.scenes) == 6, part
        assert long.n_frames > 4 * short.n_frames and long.voxel_m == short.voxel_m
        assert any(s.wind_m_s[2] == 0 for s in long.scenes)
        assert any(s.wind_m_s[2] != 0 for s in long.scenes)
        assert long.conditions == short.conditions
