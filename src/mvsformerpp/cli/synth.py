"""``mvsformerpp synth OUT``: render synthetic scenes with exact ground truth."""

from __future__ import annotations

import argparse

MAX_SIZE = 8192  # pixels per side
MAX_VIEWS = 1000
MAX_OBJECTS = 200
LAYOUTS = ("table", "ring", "room", "facade")  # mvsformerpp.synth.layouts.LAYOUTS, without importing it here


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "synth",
        help="render synthetic scenes with exact ground truth",
        description="Render procedural textured scenes from calibrated cameras into the MVSNet layout, with "
        "ground-truth depth (depth_gt/*.pfm), masks and the ground-truth surface (gt_surface.ply). "
        "With --scenes K, writes scene_0000 ... and scenes.txt (a training set).",
    )
    p.add_argument("output", metavar="OUT",
                   help="output folder: new or empty, or one that an interrupted synth run of the same settings "
                        "left, which this completes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--views", type=int, default=7)
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--objects", type=int, help="number of objects (default: 3-6, from the seed)")
    p.add_argument("--scenes", type=int, default=1, help="number of scenes (more than 1: a dataset)")
    p.add_argument("--style", choices=["classic", "train", "heldout"], default="classic",
                   help="classic: objects before a wall (tests); train: tables, rooms, facades and objects on a "
                   "ring with photo textures, gloss, exposure changes, blur and noise (the default model's training "
                   "data); heldout: a style training never sees (evaluation)")
    p.add_argument("--sensor-width", type=float, nargs=2, metavar=("LOW", "HIGH"),
                   help="train/heldout styles: each view is a window of a photo whose width in pixels is drawn from "
                   "LOW..HIGH (long focal lengths, as crops of high-resolution photos have)")
    p.add_argument("--detail", type=float, default=0.0, metavar="S",
                   help="train/heldout styles: strength in [0, 1] of fine surface detail below the scale of each "
                   "surface's texture (default 0: none), so magnified textures keep structure at the pixel scale")
    p.add_argument("--layout", choices=LAYOUTS,
                   help="train style: this kind of scene for every seed (default: drawn from the seed); room: a "
                   "handheld camera walking through a furnished room, as indoor video is")
    p.add_argument("--plain-walls", type=float, default=0.0, metavar="P",
                   help="train style: probability in [0, 1] that each wall and ceiling of a room or table is painted "
                   "one light colour, with no texture to match (most real rooms; default 0: as drawn)")
    p.add_argument("--textures", metavar="LIBRARY",
                   help="train style: draw the photo textures from this texture library (built by mvsformerpp "
                   "textures; default: scikit-image's sample photographs)")
    p.set_defaults(func=run, on_memory_error="lower --height, --width or --views")


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.errors import InputError
    from mvsformerpp.synth import generate_dataset, generate_scene
    from mvsformerpp.synth.scenes import MAX_SEED
    from mvsformerpp.synth.texture_library import read_manifest

    if args.scenes >= 1 and not 0 <= args.seed <= MAX_SEED - 1000 * (args.scenes - 1):
        raise InputError(f"--seed must be 0 .. {MAX_SEED - 1000 * (args.scenes - 1)} with --scenes {args.scenes} "
                         f"(scene k renders from seed + 1000 k, and the renderer's generators need seeds below 2^31), "
                         f"got {args.seed}")
    if args.objects is not None and not 0 <= args.objects <= MAX_OBJECTS:
        raise InputError(f"--objects must be 0 .. {MAX_OBJECTS} (every ray is tested against every object), got "
                         f"{args.objects}")
    if args.views < 2 or args.height < 32 or args.width < 32 or args.scenes < 1:
        raise InputError(f"need --views >= 2, --height/--width >= 32 and --scenes >= 1, got --views {args.views} "
                         f"--height {args.height} --width {args.width} --scenes {args.scenes}")
    if args.height > MAX_SIZE or args.width > MAX_SIZE or args.views > MAX_VIEWS:
        raise InputError(f"--height and --width must be at most {MAX_SIZE} and --views at most {MAX_VIEWS} "
                         f"(rendering needs about 100 bytes per pixel), got --height {args.height} --width "
                         f"{args.width} --views {args.views}")
    if args.sensor_width is not None:
        lo, hi = args.sensor_width
        if args.style == "classic" or not 0 < lo <= hi <= MAX_SIZE * 8:
            raise InputError(f"--sensor-width needs --style train or heldout and 0 < LOW <= HIGH <= {MAX_SIZE * 8}, "
                             f"got {lo:g} {hi:g} with --style {args.style}")
    if not 0.0 <= args.detail <= 1.0 or (args.detail and args.style == "classic"):
        raise InputError(f"--detail needs --style train or heldout and a strength in [0, 1], got {args.detail:g} "
                         f"with --style {args.style}")
    if args.layout is not None and args.style != "train":
        raise InputError(f"--layout needs --style train (the {args.style} style has one layout), got --layout "
                         f"{args.layout} with --style {args.style}")
    if not 0.0 <= args.plain_walls <= 1.0 or (args.plain_walls and args.style != "train"):
        raise InputError(f"--plain-walls needs --style train and a probability in [0, 1], got {args.plain_walls:g} "
                         f"with --style {args.style}")
    if args.textures is not None:
        if args.style != "train":
            raise InputError(f"--textures needs --style train, got --style {args.style}")
        read_manifest(args.textures)
    kw = dict(num_views=args.views, height=args.height, width=args.width, num_objects=args.objects,
              style=args.style, sensor_width=args.sensor_width, detail=args.detail, layout=args.layout,
              plain_walls=args.plain_walls, textures=args.textures)
    if args.scenes == 1:
        out = generate_scene(args.output, seed=args.seed, **kw)
    else:
        out = generate_dataset(args.output, args.scenes, seed=args.seed, **kw)
    print(f"wrote {args.scenes} scene(s) to {out}")
    return 0
