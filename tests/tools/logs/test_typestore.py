"""The log's own type store must describe its messages exactly as rosbags' ROS 2 Jazzy store does:
the same fields, the same MCAP schema text and RIHS01 hashes, so the bags are byte-identical."""
import tempfile
from pathlib import Path

import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from swerve.core.errors import ConfigError
from swerve.tools.logs.bag import TOPICS
from swerve.tools.logs.typestore import log_typestore, message_definitions

JAZZY = get_typestore(Stores.ROS2_JAZZY)
OURS = log_typestore()


def _nested(store, name, seen):
    """``name`` and every type its fields name, recursively."""
    if name not in seen:
        seen.add(name)
        for _, (kind, arg) in store.fielddefs[name][1]:
            inner = arg[0] if kind.name in ("ARRAY", "SEQUENCE") else (kind, arg)
            if inner[0].name == "NAME":
                _nested(store, inner[1], seen)
    return seen


def test_the_store_holds_exactly_the_logged_types_and_what_they_nest():
    needed = set()
    for msgtype in TOPICS.values():
        _nested(JAZZY, msgtype, needed)
    assert set(OURS.fielddefs) == needed


@pytest.mark.parametrize("name", sorted(message_definitions()))
def test_definitions_schema_text_and_hash_equal_jazzy(name):
    assert OURS.fielddefs[name] == JAZZY.fielddefs[name]
    assert OURS.generate_msgdef(name) == JAZZY.generate_msgdef(name)
    assert OURS.hash_rihs01(name) == JAZZY.hash_rihs01(name)


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="abcdefgilmnostuwxyz0123456789_/[]. TM", max_size=30))
@example("float32")
@example("b/msg/U")
@example("int32[x]")
@example("float64[36]")
@example("std_msgs/msg/Header[]")
@example("a/msg/T[]")
def test_any_field_type_is_read_or_refused_in_one_line(text):
    """A field type is a base type, a defined message type, or either as T[] / T[n]: anything
    else is refused with a ConfigError naming the file, the key and the type, never a traceback."""
    with tempfile.TemporaryDirectory() as d:
        f = Path(d, "types.yaml")
        f.write_text(yaml.safe_dump({"std_msgs/msg/Header": {"frame_id": "string"}, "a/msg/T": {"x": text}}))
        try:
            defs = message_definitions(f)
        except ConfigError as exc:
            assert "\n" not in str(exc) and "types.yaml" in str(exc) and "a/msg/T" in str(exc)
            return
    Typestore().register(defs)                  # rosbags takes what was accepted


def test_a_type_name_or_a_nested_type_the_file_lacks_is_refused(tmp_path):
    f = tmp_path / "types.yaml"
    for text, problem in (("a/T: {x: int32}\n", "'a/T' is not a message type name"),
                          ("a/msg/T: {x: b/msg/U}\n", "field x names b/msg/U, which the file does not define"),
                          ("a/msg/T: {x: a/msg/U}\na/msg/U: {y: 'a/msg/T[2]'}\n",
                           "contains itself: a/msg/T -> a/msg/U -> a/msg/T")):
        f.write_text(text)
        with pytest.raises(ConfigError, match=problem):
            message_definitions(f)
