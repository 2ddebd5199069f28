from pathlib import Path

from arlight.scene.schema import schema_markdown


def test_scene_format_reference_is_up_to_date():
    doc = (Path(__file__).parents[2] / "docs" / "scene-format.md").read_text()
    assert schema_markdown().strip() in doc, "regenerate: python -m arlight.scene.schema"
