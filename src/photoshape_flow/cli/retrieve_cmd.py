"""`photoshape retrieve`: rank the material database for a region of any photo (section 6.5).

"A user-specified region of an image may be used as input to our classifier in order to produce a
ranking of BRDFs." The region is a mask image (non-zero = inside) of the photo's size; several
``--mask`` options rank several regions in one batch.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from photoshape_flow.cli.common import console, err_console, fail, require_database, shown


def retrieve(
    image: Path = typer.Argument(..., help="Photo (any size; any background)."),
    mask: list[Path] = typer.Option(..., "--mask", "-m", help="Region mask image, non-zero inside (repeatable)."),
    classifier: int | None = typer.Option(None, "--classifier", "-c", help="Classifier id (default: newest ok)."),
    top: int = typer.Option(10, "--top", "-k", min=1, help="How many materials to list per region."),
    crop: str = typer.Option("image", help="image: pad the photo to a square; mask: square crop around the region."),
    substance_weighting: bool = typer.Option(
        True, "--substance-weighting/--no-substance-weighting",
        help="Weight material probabilities by the predicted substance's probability (paper, 5.2 Inference).",
    ),
    color_prior: bool = typer.Option(
        True, "--color-prior/--no-color-prior",
        help="Also weight by the likelihood of the region's median colour under each material, as the "
        "inference stage does (sigma fit on the validation renders; skipped when there are none).",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """Rank materials for masked regions of a photo with the trained material classifier."""
    require_database()
    import cv2
    import numpy as np
    import sqlalchemy as sa

    from photoshape_flow.config import get_settings
    from photoshape_flow.db.models import Classifier, Material
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.networks.classifiers import load_material_classifier
    from photoshape_flow.networks.evidence import stored_evidence
    from photoshape_flow.store import default_store

    if crop not in ("image", "mask"):
        fail(f"--crop must be 'image' or 'mask', got {crop!r}")
    photo = cv2.imread(str(image), cv2.IMREAD_COLOR)
    if photo is None:
        fail(f"{image}: not a readable image")
    photo = np.ascontiguousarray(photo[..., ::-1])
    masks = []
    for path in mask:
        region = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if region is None:
            fail(f"{path}: not a readable mask image")
        if region.shape != photo.shape[:2]:
            fail(f"{path}: mask is {region.shape[1]}x{region.shape[0]}, photo is {photo.shape[1]}x{photo.shape[0]}")
        if not region.any():
            fail(f"{path}: mask is empty")
        masks.append(region > 0)

    settings = get_settings()
    try:
        row, model = load_material_classifier(classifier, settings)
    except (LookupError, ValueError) as exc:
        fail(str(exc))
    material_probs, substance_probs = model.predict(photo, masks, crop=crop)  # type: ignore[arg-type]
    with session_scope(settings.resolved_database_url) as session:
        evidence = stored_evidence(session, default_store(settings), session.get(Classifier, row.id), model,
                                   color=color_prior)
    prior = evidence.color_prior
    # with crop="mask" the head sees the region enlarged: its size in the photo does not matter
    parts = evidence.rank_regions(photo, masks, material_probs, substance_probs if substance_weighting else None,
                                  top, measured=crop == "image")
    ranked = []
    for path, region, part in zip(mask, masks, parts, strict=True):
        if not part.head_used:
            err_console.print(f"[yellow]warning:[/] {path}: the region covers {region.mean():.2%} of the photo, "
                              f"less than the {evidence.policy.min_region_fraction:.1%} the classifier was trained "
                              "on: ranked without its material head (or use --crop mask)", highlight=False)
        ranked.append(part.materials)
    ids = sorted({r.material_id for regions in ranked for r in regions})
    with session_scope(settings.resolved_database_url) as session:
        rows = session.execute(sa.select(Material.id, Material.name).where(Material.id.in_(ids)))
        names = {int(r.id): str(r.name) for r in rows}

    if as_json:
        payload = {
            "classifier": {"id": row.id, "name": row.name},
            "color_sigma": prior[1] if prior is not None else None,
            "regions": [
                {"mask": str(path), "materials": [
                    {"rank": i + 1, "material_id": r.material_id, "name": names.get(r.material_id),
                     "substance": r.substance, "score": r.score, "posterior": r.posterior,
                     "probability": r.probability}
                    for i, r in enumerate(regions)
                ]}
                for path, regions in zip(mask, ranked, strict=True)
            ],
        }
        console.print_json(json.dumps(payload))
        return
    colour_note = f", colour likelihood sigma {prior[1]:.1f}" if prior is not None else ""
    console.print(f"classifier {row.id} ({row.name}, {row.architecture}){colour_note}", highlight=False)
    for path, regions in zip(mask, ranked, strict=True):
        table = Table(title=f"{path.name}")
        for column in ("rank", "material", "substance", "posterior", "score", "p(material)"):
            table.add_column(column, justify="left" if column in ("material", "substance") else "right")
        for i, r in enumerate(regions, start=1):
            table.add_row(str(i), shown(names.get(r.material_id, f"#{r.material_id}")), r.substance,
                          f"{r.posterior:.3f}", f"{r.score:.4f}", f"{r.probability:.4f}")
        console.print(table)


def register(app: typer.Typer) -> None:
    app.command("retrieve")(retrieve)
