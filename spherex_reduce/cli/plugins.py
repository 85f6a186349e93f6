"""``spherex-reduce plugins``: what each plugin provides."""

from ..reduce.plugins import BLOCK_ENV, Registry, blocked_plugins, plugin_distributions


def add_parser(sub):
    p = sub.add_parser("plugins", help="list steps, strategies and simulators and their plugins",
                       description="List every registered step (with its FITS status keyword "
                       "and the kind of its strategies), strategy and simulator, with the plugin "
                       "that provides it and the distribution (and version) that installed the "
                       f"plugin. Block plugins by name with {BLOCK_ENV}=name1,name2.")
    p.set_defaults(func=run)


def _columns(rows):
    """Rows of strings as left-aligned columns two spaces apart."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  ".join(f"{c:<{w}}" for c, w in zip(r, widths, strict=True)).rstrip()
            for r in rows]


def run(args):
    registry = Registry()
    dists = plugin_distributions()
    rows = [("kind", "name", "keyword", "strategies", "plugin", "distribution")]

    def add(kind, name, reg, keyword="", strategies=""):
        rows.append((kind, name, keyword, strategies, reg.plugin, dists.get(reg.plugin, "-")))

    for name, reg in sorted(registry.steps.items()):
        add("step", name, reg, reg.obj.keyword, reg.obj.strategy_kind or "")
    for kind, options in sorted(registry.strategies.items()):
        for name, reg in sorted(options.items()):
            add("strategy", f"{kind}/{name}", reg)
    for name, reg in sorted(registry.simulators.items()):
        add("simulator", name, reg)
    print("\n".join(_columns(rows)))
    blocked = blocked_plugins()
    if blocked:
        print(f"blocked: {', '.join(sorted(blocked))}")
