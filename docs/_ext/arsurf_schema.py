"""Sphinx directive ``.. session-tick-fields::``: the table of a session's per-tick datasets, generated
at every build from :data:`arsurf.sessions.schema.TICK_FIELDS` and the optional fields beside it, so
the page can never lag behind the code (tests/project/test_docs.py checks that it lists them all)."""
from __future__ import annotations

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective


def tick_field_rows() -> list[tuple[str, str, str, str, str, str]]:
    """(name, shape, dtype, unit, fill, meaning) of every per-tick dataset a session may hold."""
    from arsurf.sessions import schema

    rows = []
    optional = {schema.SAFETY_FLAGS.name: "optional: older files lack it",
                schema.TUBE_POSES.name: "optional: sessions with nano-objects; shape (n, k, 3)",
                schema.INSTRUMENT_POSITION.name: "optional: sessions driven by an instrument"}
    for field in (*schema.TICK_FIELDS, schema.SAFETY_FLAGS, schema.TUBE_POSES, schema.INSTRUMENT_POSITION):
        meaning = field.doc + (f" ({optional[field.name]})" if field.name in optional else "")
        rows.append((field.name, field.shape_text, field.dtype, field.unit, repr(field.fill), meaning))
    return rows


class SessionTickFields(SphinxDirective):
    """The list-table of :func:`tick_field_rows`."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        lines = [".. list-table::", "   :header-rows: 1", "   :widths: 18 10 6 8 8 50", "",
                 "   * - dataset", "     - shape", "     - dtype", "     - unit", "     - fill", "     - meaning"]
        for name, shape, dtype, unit, fill, meaning in tick_field_rows():
            lines += [f"   * - ``{name}``", f"     - {shape}", f"     - ``{dtype}``", f"     - ``{unit}``",
                      f"     - ``{fill}``", f"     - {meaning}"]
        node = nodes.container()
        self.state.nested_parse(StringList(lines, source="arsurf.sessions.schema"), self.content_offset, node)
        return node.children


def setup(app):
    app.add_directive("session-tick-fields", SessionTickFields)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
