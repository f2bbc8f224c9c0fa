"""Project files: exact save/reload, atomic replacement, clear errors for unknown fields and newer versions."""
import json

import numpy as np
import pytest

from x2video.edits import AlbedoSet, Edits, Exposure, Mask, MaskOut, Project, Reference, ScalarOp, load_project, save_project


def _project(tmp_path):
    rng = np.random.default_rng(0)
    m = Mask(ids=[3, 4])
    m.paint(0, rng.random((6, 9)))
    m.paint(5, rng.random((6, 9)) > 0.5)
    e = Edits(
        masks={"sofa": m, "wall": Mask(hold=True)},
        ops=[AlbedoSet(mask="sofa", color=(0.1, 0.2, 0.3)), Exposure(stops=0.5), MaskOut(mask="sofa"),
             ScalarOp(mask="wall", target_channel="metallic", mode="scale", value=2)],
        dropped={"normal"},
        global_prompt="evening",
        local_prompts={"sofa": "blue velvet"},
        reference=Reference(path="ref.png"),
    )
    e.masks["wall"].paint(2, np.ones((6, 9)))
    return Project(shot=str(tmp_path / "shots" / "a"), edits=e)


def test_round_trip_exact(tmp_path):
    p = _project(tmp_path)
    save_project(tmp_path / "p.x2v.json", p)
    back = load_project(tmp_path / "p.x2v.json")
    assert back.edits == p.edits and back.shot == str((tmp_path / "shots" / "a").resolve())
    doc = json.loads((tmp_path / "p.x2v.json").read_text())
    assert doc["version"] == 1 and doc["shot"] == "shots/a"
    assert len(list((tmp_path / "p.x2v.masks").glob("*.npz"))) == 2
    # edit and save again: stale mask files go, nothing half-written remains
    p.edits.remove_mask("wall")
    save_project(tmp_path / "p.x2v.json", p)
    assert len(list((tmp_path / "p.x2v.masks").glob("*.npz"))) == 1
    assert not [f for f in tmp_path.rglob(".*tmp*")]
    assert load_project(tmp_path / "p.x2v.json").edits == p.edits


def test_save_failure_keeps_old_file(tmp_path, monkeypatch):
    p = _project(tmp_path)
    save_project(tmp_path / "p.json", p)
    before = (tmp_path / "p.json").read_bytes()
    import x2video.io.atomic as atomic

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "replace", boom)
    p.edits.global_prompt = "changed"
    with pytest.raises(OSError):
        save_project(tmp_path / "p.json", p)
    monkeypatch.undo()
    assert (tmp_path / "p.json").read_bytes() == before
    assert load_project(tmp_path / "p.json").edits.global_prompt == "evening"


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(version=2), "version 2 is newer"),
        (lambda d: d.update(colour="red"), r"unknown field\(s\) colour"),
        (lambda d: d["edits"].update(extra=1), r"edits: unknown field\(s\) extra"),
        (lambda d: d["edits"]["ops"][0].update(strength=1), r"edits.ops\[0\]: unknown field\(s\) strength"),
        (lambda d: d["edits"]["masks"]["sofa"].update(feather=2), r"edits.masks\['sofa'\]: unknown field\(s\) feather"),
        (lambda d: d.update(format="other"), "field 'format'"),
        (lambda d: d["edits"]["ops"][1].update(mask="ghost"), r"ops\[1\].*'ghost' does not exist"),
        (lambda d: d["mask_files"].update(sofa="p.masks/none.npz"), "mask 'sofa': mask file .* is missing"),
    ],
)
def test_bad_project_files(tmp_path, change, message):
    save_project(tmp_path / "p.json", _project(tmp_path))
    doc = json.loads((tmp_path / "p.json").read_text())
    change(doc)
    (tmp_path / "p.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=message) as err:
        load_project(tmp_path / "p.json")
    assert "p.json" in str(err.value)


def test_not_json(tmp_path):
    (tmp_path / "p.json").write_text("{nope")
    with pytest.raises(ValueError, match="p.json: not valid JSON"):
        load_project(tmp_path / "p.json")
    with pytest.raises(FileNotFoundError):
        load_project(tmp_path / "none.json")


def test_is_project_file_and_remove(tmp_path):
    from x2video.edits import PROJECT_SUFFIX, is_project_file, remove_project
    from x2video.edits.project import masks_dir

    path = tmp_path / f"p{PROJECT_SUFFIX}"
    save_project(path, _project(tmp_path))
    assert is_project_file(path) and masks_dir(path).is_dir()
    (tmp_path / "shot.json").write_text('{"format": "x2video-project"}')
    (tmp_path / "other.json").write_text('{"format": "x2video-shot"}')
    assert not is_project_file(tmp_path / "shot.json") and not is_project_file(tmp_path / "other.json")
    remove_project(path)
    assert not path.exists() and not masks_dir(path).exists()
    remove_project(path)  # gone already: no error
