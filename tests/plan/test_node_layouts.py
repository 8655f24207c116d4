"""A config's node layouts (omnican.plan.node.node_layouts) worked out once for the
simulator's wiring and the host opening on the same config object (--sim), again for
another config or an EDS file changed on disk; what they hold is what a fresh layout
holds."""

from __future__ import annotations

import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from omnican.config import default_config
from omnican.plan import node as plan_node
from omnican.plan.node import NodeLayout, node_layouts
from tests.support.helpers import lockstep_rig


def _held(layout: NodeLayout) -> tuple[Any, ...]:
    return (layout.node_id, layout.eds, layout.mode, layout.stages,
            [(a.wheel_index, a.wheel, a.target, a.position, a.stage) for a in layout.axes],
            layout.plan, layout.health, layout.estop_entry, layout.sdo_writes,
            layout.has_consumer, sorted(layout.dictionary.names))


def test_one_config_object_is_laid_out_once_and_as_a_fresh_layout() -> None:
    cfg = default_config()
    first = node_layouts(cfg)
    again = node_layouts(cfg)
    assert again == first and again is not first  # the same layouts, a list of its own
    assert all(a is b for a, b in zip(again, first, strict=True))
    plan_node._LAST = None
    fresh = node_layouts(cfg)
    assert [_held(x) for x in fresh] == [_held(x) for x in first]
    other = replace(cfg)  # equal, but another config object: laid out anew
    assert all(a is not b for a, b in zip(node_layouts(other), fresh, strict=True))


def test_an_eds_file_changed_on_disk_is_laid_out_again(tmp_path: Path) -> None:
    cfg = default_config()
    path = tmp_path / "drive.eds"
    shutil.copy(cfg.wheels[0].eds, path)
    cfg = replace(cfg, wheels=tuple(replace(w, eds=path) for w in cfg.wheels))
    first = node_layouts(cfg)
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1))
    assert all(a is not b for a, b in zip(node_layouts(cfg), first, strict=True))
    path.unlink()
    with pytest.raises(Exception, match="EDS file not found"):
        node_layouts(cfg)


def test_a_simulated_base_and_its_host_lay_the_config_out_once(
        channel: str, monkeypatch: pytest.MonkeyPatch) -> None:
    made: list[int] = []
    real = NodeLayout.__init__

    def counted(self: NodeLayout, node_id: int, *args: Any, **kwargs: Any) -> None:
        made.append(node_id)
        real(self, node_id, *args, **kwargs)

    monkeypatch.setattr(NodeLayout, "__init__", counted)
    with lockstep_rig(channel) as (clock, _sim, base):
        clock.sleep(0.05)
        assert all(w.online for w in base.wheels)
    assert made == [1, 2, 3]
