"""``gltrack refine-masks DATASET RESULT``: refine a dataset's foreground masks with a tracked
result's silhouettes, then track again (:mod:`gltrack.data.refine_masks`)."""
from __future__ import annotations

NAME = "refine-masks"
HELP = ("refine a recorded dataset's foreground masks with the silhouettes of a tracked result "
        "(the still parts the sequence's background kept, e.g. a seated torso); track again after")


def add_arguments(p):
    from gltrack.data.refine_masks import METHODS
    from gltrack.observe.model_masks import BAND_M, REACH_M

    p.add_argument("dataset", help="multi-view dataset folder with masks (gltrack ingest)")
    p.add_argument("result", help="results folder tracked on that dataset (look at its overlay "
                                  "first: a track that is off the person refines the masks wrong)")
    p.add_argument("--method", choices=METHODS, default="grabcut",
                   help="background: estimate the sequence's foreground again with the model's "
                        "silhouettes left out of the background statistics "
                        "(removes the subject's ghost, finds parts that never move); grabcut: "
                        "GrabCut per frame seeded by the model, the sequence's mask kept within "
                        "--reach; scene: drop the mask's pixels that show the static scene "
                        "(they match their temporal background, never the subject's ghost) "
                        "away from the model's silhouette (removes background that GrabCut took "
                        "for the subject by its colours; adds nothing)")
    p.add_argument("--band", type=float, default=BAND_M, metavar="M",
                   help="metres around the model's silhouette where the colour segmentation "
                        "decides (beyond: background)")
    p.add_argument("--reach", type=float, default=REACH_M, metavar="M",
                   help="metres around the model's silhouette within which the sequence's own "
                        "mask is kept (a hand the model missed); farther foreground is dropped")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="refine only the result's frames A (inclusive) to B (exclusive): the "
                        "stretch where its overlay shows the model on the person; default: all")


def run(args) -> int:
    from gltrack.data.refine_masks import refine_dataset_masks

    from .common import UsageError, parse_frames

    for flag, v in (("--band", args.band), ("--reach", args.reach)):
        if not 0.0 < v <= 2.0:
            raise UsageError(f"{flag} must be in (0, 2] metres, got {v:g}")
    frames = parse_frames(args.frames) if args.frames is not None else None
    rec = refine_dataset_masks(args.dataset, args.result, method=args.method,
                               band_m=args.band, reach_m=args.reach,
                               frames=frames, progress=not args.quiet)
    if not args.quiet:
        print(f"{args.dataset}: masks of {rec['frames']} frames refined with {args.result} in "
              f"{rec['seconds']:.0f} s; foreground fraction per camera "
              f"{rec['foreground_fraction_before']} -> {rec['foreground_fraction_after']} "
              f"(the sequence's masks are kept in camN_mask_sequence/); track again to use them")
    return 0
