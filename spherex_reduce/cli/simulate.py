"""``spherex-reduce simulate``: simulate a scene to a FITS file."""

from ..io import atomic_output
from ._common import check_paths


def add_parser(sub):
    p = sub.add_parser("simulate", help="simulate raw ramps or a slope image from a scene",
                       description="Simulate the readout noise of a scene (YAML; every key "
                       "optional, defaults = the paper's Table 2/3 case) and write OUT.fits. "
                       "Ramps are streamed to disk frame by frame.")
    p.add_argument("scene", metavar="SCENE.yaml", nargs="?", default=None,
                   help="scene file (default: the paper's case)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.fits")
    p.add_argument("--mode", choices=["ramps", "slopes"], default=None,
                   help="override output.mode")
    p.add_argument("--seed", type=int, default=None, help="override the scene's seed")
    p.add_argument("--overwrite", action="store_true", help="replace OUT.fits if it exists")
    p.set_defaults(func=run)


def run(args):
    from ..simulation import load_scene, simulate_to_fits

    check_paths([args.scene], [args.output])
    scene = load_scene(args.scene)
    atomic_output(args.output, args.overwrite)  # refuse before computing
    mode = args.mode or scene.mode
    path = simulate_to_fits(scene, args.output, mode=mode, seed=args.seed,
                            overwrite=args.overwrite, progress=not args.quiet)
    print(f"wrote {path} ({mode}, {scene.schedule.summary()})")
