"""``spherex-reduce show-config``: the effective, validated pipeline config."""

from ..config import shipped_configs
from ..pipeline import Pipeline


def add_parser(sub):
    p = sub.add_parser("show-config", help="print a pipeline config with every default filled in",
                       description="Validate a pipeline YAML file (or shipped config name) and "
                       "print the effective configuration.")
    p.add_argument("config", nargs="?", metavar="PIPELINE.yaml")
    p.add_argument("--list", action="store_true", help="list the shipped configs")
    p.set_defaults(func=run)


def run(args):
    if args.list or not args.config:
        if not args.list:
            print("give PIPELINE.yaml or a shipped name; shipped configs:")
        for name in shipped_configs():
            print(name)
        return 0 if args.list else 2
    pipeline = Pipeline.from_yaml(args.config)
    print(f"# {pipeline.source}, config hash {pipeline.config_hash}")
    print(pipeline.to_yaml(), end="")
