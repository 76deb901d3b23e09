"""The README's generated tables are what the code says (they cannot drift)."""

from __future__ import annotations

from pathlib import Path

from rbgen.settings import options_table

README = Path(__file__).resolve().parents[1] / "README.md"


def test_options_table_is_the_settings_table():
    text = README.read_text()
    begin = text.index("<!-- options-table:begin")
    body = text[text.index("\n", begin) + 1 : text.index("<!-- options-table:end -->")]
    assert body.strip() == options_table().strip()
