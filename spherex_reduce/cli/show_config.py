"""``spherex-reduce show-config``: the effective, validated pipeline config."""

from ..io.config import shipped_configs
from ..reduce.pipeline import Pipeline


def add_parser(sub):
    p = sub.add_parser("show-config", help="print a pipeline config with every default filled in",
                       description="Validate a pipeline YAML file (or shipped config name) and "
                       "print the effective configuration.")
    p.add_argument("config", nargs="?", metavar="PIPELINE.yaml")
    p.add_argument("--list", action="store_true",
                   help="list the shipped configs, each with its description")
    p.set_defaults(func=run)


def run(args):
    if args.list or not args.config:
        if not args.list:
            print("give PIPELINE.yaml or a shipped name; shipped configs:")
        names = shipped_configs()
        width = max(map(len, names))
        for name in names:
            description = Pipeline.from_yaml(name).config.get("description", "")
            print(f"{name:<{width}}  {description}".rstrip())
        return 0 if args.list else 2
    pipeline = Pipeline.from_yaml(args.config)
    print(f"# {pipeline.source}, config hash {pipeline.config_hash}")
    print(pipeline.to_yaml(), end="")
