import json

import jax
import numpy as np
import pytest

from jaxhop import InputError
from jaxhop._core.terrain import (
    builtin_terrain,
    load_terrain,
    make_terrain,
    random_terrain,
    save_terrain,
    segments,
    terrain_from_dict,
)


def test_reference_segments_and_edge_distance():
    t = builtin_terrain("reference")
    segs = segments(t)
    assert segs.n == 60
    centre = np.asarray(segs.centre)
    blocks = t.blocks()
    for (y, h), b, de in zip(centre, np.asarray(segs.block), np.asarray(segs.edge_distance)):
        s, e, hb = blocks[b]
        assert s + 0.075 - 1e-12 <= y <= e - 0.075 + 1e-12 and h == hb
        assert de == pytest.approx(min(y - s, e - y))
    # Segments of a block are contiguous and exactly 2l long.
    on_first = centre[np.asarray(segs.block) == 0, 0]
    assert np.allclose(np.diff(on_first), 0.15)


def test_segments_centred_with_leftover():
    t = make_terrain([(0.0, 1.0, 0.0)], (0.5, 1.3, 0.0))
    c = np.asarray(segments(t).centre)[:, 0]
    assert c.size == 6  # floor(1.0 / 0.15)
    assert c[0] - 0.075 == pytest.approx(1.0 - (c[-1] + 0.075))


@pytest.mark.parametrize("blocks, needle", [
    ([], "empty"),
    ([(0, 1, float("nan"))], "finite"),
    ([(1.0, 0.5, 0.0)], "start 1.0 must be less than end"),
    ([(0, 1, 0), (0.5, 2, 0)], "overlaps"),
    ([(2, 3, 0), (0, 1, 0)], "not sorted"),
    ([(0, 0.1, 0)], "no block is at least one segment"),
])
def test_invalid_blocks_name_the_rule(blocks, needle):
    with pytest.raises(InputError, match=needle):
        make_terrain(blocks)


def test_json_round_trip(tmp_path):
    t = builtin_terrain("long")
    path = tmp_path / "long.json"
    save_terrain(t, str(path))
    back = load_terrain(str(path))
    assert back.blocks() == t.blocks() and back.goal == t.goal and back.name == "long"


@pytest.mark.parametrize("data, needle", [
    ([1, 2], "expected a JSON object"),
    ({"name": "x"}, "missing key 'blocks'"),
    ({"blocks": [{"start": 0, "end": 1}]}, r"blocks\[0\]: missing key\(s\) height"),
    ({"blocks": [{"start": 0, "end": "1", "height": 0}]}, r"blocks\[0\].end: expected a number"),
    ({"blocks": [{"start": 0, "end": 1, "height": 0}], "colour": 1}, "unknown key"),
    ({"blocks": [{"start": 0, "end": 1, "height": 0}], "goal": [1, 2]}, "goal"),
    ({"blocks": [{"start": 0, "end": 1, "height": True}]}, "expected a number"),
])
def test_json_validation(data, needle):
    with pytest.raises(InputError, match=needle):
        terrain_from_dict(data)


def test_random_terrain_is_seeded_and_valid():
    a = random_terrain(jax.random.key(3), 10.0)
    b = random_terrain(jax.random.key(3), 10.0)
    c = random_terrain(jax.random.key(4), 10.0)
    assert a.blocks() == b.blocks() and a.blocks() != c.blocks()
    for s, e, _ in a.blocks():
        n = (e - s) / 0.15
        assert abs(n - round(n)) < 1e-6
    # Round trip through the validating loader.
    assert terrain_from_dict(json.loads(json.dumps(a.to_dict()))).blocks() == a.blocks()
