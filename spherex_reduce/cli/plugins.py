"""``spherex-reduce plugins``: what each plugin provides."""

from ..plugins import BLOCK_ENV, Registry, blocked_plugins


def add_parser(sub):
    p = sub.add_parser("plugins", help="list steps, strategies and simulators and their plugins",
                       description="List every registered step, strategy and simulator with the "
                       f"plugin that provides it. Block plugins with {BLOCK_ENV}=name1,name2.")
    p.set_defaults(func=run)


def run(args):
    registry = Registry()
    rows = []
    for name, reg in sorted(registry.steps.items()):
        extra = f" [{reg.obj.keyword}]"
        if reg.obj.strategy_kind:
            extra += f" strategies: {reg.obj.strategy_kind}"
        rows.append(("step", name + extra, reg.plugin))
    for kind, options in sorted(registry.strategies.items()):
        for name, reg in sorted(options.items()):
            rows.append(("strategy", f"{kind}/{name}", reg.plugin))
    for name, reg in sorted(registry.simulators.items()):
        rows.append(("simulator", name, reg.plugin))
    width = max(len(r[1]) for r in rows)
    print(f"{'kind':<10} {'name':<{width}} plugin")
    for kind, name, plugin in rows:
        print(f"{kind:<10} {name:<{width}} {plugin}")
    blocked = blocked_plugins()
    if blocked:
        print(f"blocked: {', '.join(sorted(blocked))}")
