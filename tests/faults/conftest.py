"""The fault suite (issue 44): hostile inputs and faults, each answered by a clear message (no traceback) or a valid
render, and never a half-written file. Fixtures: tiny shots on disk, a size-limited folder (a real tmpfs where this
machine lets us mount one, else a simulated full disk: see `small_disk`)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: sampling_fake, app_helpers

from faults_helpers import SmallDisk, tiny_shot_dir  # noqa: E402


@pytest.fixture(scope="session")
def shot_dir(tmp_path_factory) -> Path:
    """A 4-frame 24x32 shot folder (albedo, normal, irradiance), read-only by convention: copy it to change it."""
    return tiny_shot_dir(tmp_path_factory.mktemp("faults") / "shot", frames=4, h=24, w=32)


@pytest.fixture
def small_disk(tmp_path, request):
    """A folder on a device with little room: `SmallDisk(tmp_path / 'disk', size)`; `disk.real` says whether it is a
    real tmpfs (root, mount allowed) or a simulated full disk (ENOSPC raised by the low-level image and file writes
    once the budget is spent). Each test says which ran (`record_property('disk', ...)`)."""
    disks: list[SmallDisk] = []

    def make(size: int) -> SmallDisk:
        disk = SmallDisk(tmp_path / f"disk{len(disks)}", size)
        disks.append(disk)
        request.node.user_properties.append(("disk", "tmpfs" if disk.real else "simulated ENOSPC"))
        print(f"small disk {disk.path}: {'a real tmpfs' if disk.real else 'simulated ENOSPC (no mount here)'} of {size} bytes")
        return disk

    yield make
    for d in disks:
        d.close()
