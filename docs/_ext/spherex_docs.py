"""Sphinx directives that render parts of the documentation from the code itself.

``.. spherex-reduce-help:: [COMMAND]``
    The ``--help`` text of ``spherex-reduce`` or one of its subcommands.
``.. spherex-reduce-steps::``
    A table of the steps of the package's own plugins: name, FITS status
    keyword, plugin, and every parameter with its default and description.
``.. spherex-reduce-strategies::``
    The same for the strategies.
``.. spherex-reduce-configs::``
    The text of every pipeline configuration shipped with the package.
``.. spherex-reduce-dq::``
    The data-quality bits of `spherex_reduce.core.dq` with their ``#:`` comments.

Only the package's own plugins are listed (no entry points), so the pages do
not depend on which third-party plugins happen to be installed.
"""

import argparse
import os

from docutils import nodes
from docutils.parsers.rst import Directive


def _literal(text, language="none"):
    node = nodes.literal_block(text, text)
    node["language"] = language
    return node


def _para(*parts):
    """A paragraph from strings (plain) and 1-tuples (inline literal)."""
    p = nodes.paragraph()
    for part in parts:
        p += nodes.literal(part[0], part[0]) if isinstance(part, tuple) else nodes.Text(part)
    return p


def _table(header, rows, widths):
    table = nodes.table()
    group = nodes.tgroup(cols=len(header))
    table += group
    for w in widths:
        group += nodes.colspec(colwidth=w)

    def row(cells):
        r = nodes.row()
        for cell in cells:
            entry = nodes.entry()
            for item in cell if isinstance(cell, list) else [cell]:
                entry += item if isinstance(item, nodes.Node) else _para(item)
            r += entry
        return r

    thead = nodes.thead()
    thead += row(header)
    group += thead
    body = nodes.tbody()
    for cells in rows:
        body += row(cells)
    group += body
    return table


def _registry():
    from spherex_reduce.reduce.plugins import Registry, get_plugin_manager

    return Registry(get_plugin_manager(entry_points=False))


def _yaml_value(value):
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, str) else str(value)


def _parameter_items(parameters):
    if not parameters:
        return [_para("(none)")]
    items = nodes.bullet_list()
    for p in parameters:
        text = f" (default {_yaml_value(p.default)})"
        if p.choices:
            text += f", one of {', '.join(_yaml_value(c) for c in p.choices)}"
        if p.bounds:
            text += f", {p.bounds}"
        item = nodes.list_item()
        item += _para((p.name,), text + (f": {p.doc}" if p.doc else ""))
        items += item
    return [items]


class CliHelp(Directive):
    required_arguments = 0
    optional_arguments = 1

    def run(self):
        from spherex_reduce.cli import build_parser

        saved = os.environ.get("COLUMNS")
        os.environ["COLUMNS"] = "90"  # argparse wraps to the terminal width
        try:
            parser = build_parser()
            if self.arguments:
                name = self.arguments[0]
                subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
                if not subs or name not in subs[0].choices:
                    raise self.error(f"spherex-reduce has no subcommand {name!r}")
                parser = subs[0].choices[name]
            text = parser.format_help().rstrip()
        finally:
            if saved is None:
                os.environ.pop("COLUMNS", None)
            else:
                os.environ["COLUMNS"] = saved
        return [_literal(text)]


class StepTable(Directive):
    def run(self):
        reg = _registry()
        rows = []
        for name, r in reg.steps.items():
            cls = r.obj
            params = list(cls.parameters)
            first = [_para((name,))]
            if cls.strategy_kind:
                first.append(
                    _para(
                        f"strategies of kind {cls.strategy_kind!r}, default ",
                        (str(cls.default_strategy),),
                    )
                )
            rows.append(
                [first, [_para((cls.keyword,))], [_para(r.plugin)], _parameter_items(params)]
            )
        return [_table(["Step", "Keyword", "Plugin", "Parameters"], rows, [22, 12, 11, 55])]


class StrategyTable(Directive):
    def run(self):
        reg = _registry()
        rows = []
        for kind, options in reg.strategies.items():
            for name, r in options.items():
                doc = (r.obj.__doc__ or "").strip().splitlines()
                rows.append(
                    [
                        [_para((f"{kind}/{name}",))],
                        [_para(r.plugin)],
                        [_para(doc[0] if doc else ""), *_parameter_items(r.obj.parameters)],
                    ]
                )
        return [_table(["Kind/name", "Plugin", "What it does, parameters"], rows, [20, 12, 68])]


class ShippedConfigs(Directive):
    def run(self):
        from spherex_reduce.io.config import resolve_config, shipped_configs

        out = []
        for name in shipped_configs():
            text, _ = resolve_config(name)
            out.append(_para((name,), f"  (spherex-reduce reduce IN.fits -c {name} -o OUT.fits)"))
            out.append(_literal(text.rstrip(), "yaml"))
        return out


class DQTable(Directive):
    def run(self):
        from sphinx.pycode import ModuleAnalyzer

        from spherex_reduce import dq

        docs = ModuleAnalyzer.for_module("spherex_reduce.core.dq").find_attr_docs()
        rows = []
        for name in dq.__all__:
            value = getattr(dq, name)
            if isinstance(value, int) and value & (value - 1) == 0:  # one bit each
                doc = " ".join(docs.get(("", name), [])).strip()
                meaning = nodes.paragraph()
                meaning += self.state.inline_text(doc, self.lineno)[0]
                image = "informs" if value & dq.INFORMATIONAL else "do not use"
                read = "usable" if value & dq.READ_INFORMATIONAL else "not used"
                rows.append([_para(str(value)), [_para((name,))], meaning, _para(read),
                             _para(image)])
        rows.sort(key=lambda r: int(r[0].astext()))
        return [_table(["Value", "Name", "Meaning", "A read", "A pixel of an image"], rows,
                       [8, 18, 50, 10, 14])]


def setup(app):
    app.add_directive("spherex-reduce-help", CliHelp)
    app.add_directive("spherex-reduce-steps", StepTable)
    app.add_directive("spherex-reduce-strategies", StrategyTable)
    app.add_directive("spherex-reduce-configs", ShippedConfigs)
    app.add_directive("spherex-reduce-dq", DQTable)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
