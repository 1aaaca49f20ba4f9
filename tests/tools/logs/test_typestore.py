"""The log's own type store must describe its messages exactly as rosbags' ROS 2 Jazzy store does:
the same fields, the same MCAP schema text and RIHS01 hashes, so the bags are byte-identical."""
import pytest
from rosbags.typesys import Stores, get_typestore

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


@pytest.mark.parametrize("text, problem", [
    ("a/msg/T: {x: float32}\n", "unknown field type 'float32'"),
    ("a/msg/T: {x: b/msg/U}\n", "field x names b/msg/U, which the file does not define"),
    ("a/T: {x: int32}\n", "'a/T' is not a message type name"),
    ("a/msg/T: {x: 'int32[x]'}\n", "unknown field type 'int32\\[x\\]'"),
])
def test_a_bad_definition_file_names_the_problem(tmp_path, text, problem):
    f = tmp_path / "types.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=problem):
        message_definitions(f)
