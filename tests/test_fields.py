"""The one schema-table checker of the TOML readers (plants, the mirror, the generic stack, studies)."""

import pytest

from workbench.errors import PlantDefinitionError, StudyDefinitionError
from workbench.fields import Field, check_table

SCHEMA = {"a_m": Field("float", 0.0, 1.0, expect="a length in m"), "b": Field("str", expect="a name", required=False)}


def test_values_checked_and_returned():
    assert check_table("f.toml", "sec", {"a_m": 0.5}, SCHEMA, PlantDefinitionError) == {"a_m": 0.5}


@pytest.mark.parametrize("table, key, text", [
    ({"a_m": 0.5, "c": 1}, "sec.c", "unknown key (value 1); known keys here: a_m, b"),
    ({}, "sec.a_m", "missing; expected a length in m (see x.toml)"),
    ({"a_m": 2.0}, "sec.a_m", "got 2.0"),
])
def test_each_fault_names_file_and_key(table, key, text):
    with pytest.raises(StudyDefinitionError) as err:
        check_table("f.toml", "sec", table, SCHEMA, StudyDefinitionError, missing_hint="see x.toml")
    assert err.value.key == key and str(err.value).startswith(f"f.toml: [{key}]") and text in str(err.value)


def test_top_level_sections_skipped_but_must_be_tables():
    top = {"a_m": 0.1, "sec": {"x": 1}}
    assert check_table("f.toml", "", top, SCHEMA, PlantDefinitionError, sections=("sec",)) == {"a_m": 0.1}
    with pytest.raises(PlantDefinitionError, match=r"\[sec\] must be a table \[sec\], got 5"):
        check_table("f.toml", "", {"a_m": 0.1, "sec": 5}, SCHEMA, PlantDefinitionError, sections=("sec",))


@pytest.mark.parametrize("content, key, text", [
    (None, "file", "cannot be read (No such file or directory); check the path"),
    (b"a = \xff\xfe\n", "file", "is not UTF-8 text (byte 4)"),
    (b"a = = 1\n", "syntax", "is not valid TOML"),
])
def test_read_toml_names_file_and_fault(tmp_path, content, key, text):
    from workbench.fields import read_toml
    path = tmp_path / "p.toml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(PlantDefinitionError) as err:
        read_toml(path, PlantDefinitionError)
    assert err.value.key == key and text in str(err.value) and str(path) in str(err.value)
