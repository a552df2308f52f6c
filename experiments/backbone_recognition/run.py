"""Train classifier arms on one collection's renders and score them on its validation renders made photo-like.

    PHOTOSHAPE_DATA_ROOT=... python -m experiments.backbone_recognition.run \\
        --arm scratch=cpu --arm backbone=backbone --arm noaug=backbone:augment.jpeg_quality=0 --out arms.json

Each arm is `name=preset[:field=value,...]` (dotted fields reach the augmentation). Arms train through
the pipeline's own `run_training` on the collection's training and bootstrap renders (a new classifier
row each; run it on a scratch copy of the database: the newest row is what inference reads). They are
scored on the validation renders (shapes and envmaps no arm trained on), degraded like exemplars and
with misaligned part maps (`recognition.bn_prior.photo_cases`), never on exemplars: material top-1 /
top-5 over the enabled materials, substance top-1 of the substance head and of the material head's
mass per substance, with 95% bootstrap intervals over renders.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.configs import AugmentConfig, get_config
from photoshape_flow.classify.substance_configs import read_side_of
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.devices import set_torch_threads
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.recognition.bn_prior import photo_cases
from photoshape_flow.recognition.material_sets import material_set
from photoshape_flow.recognition.training import run_training
from photoshape_flow.store import BlobStore

from ..common import interval, region_hits, results_dir


def arm_config(spec: str):
    """`preset[:field=value,...]` -> a ClassifierConfig (``augment.x=`` fields reach the augmentation)."""
    preset, _, rest = spec.partition(":")
    config = get_config(preset)
    augment: dict[str, Any] = {}
    fields: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, _, raw = item.partition("=")
        value = json.loads(raw) if raw[:1] in "0123456789-[{tf" else raw
        (augment if key.startswith("augment.") else fields)[key.removeprefix("augment.")] = value
    if augment:
        fields["augment"] = replace(config.augment, **augment) if config.augment else AugmentConfig(**augment)
    return config.replace(**fields)


def score(model: Any, cases: list, enabled: set[int]) -> dict[str, Any]:
    """Per-region hits of material top-1/top-5 and substance (head, material mass), with per-render groups.

    Rows of "hits": render, top-1, top-5, substance of the substance head, substance of the mass.
    """
    hits = region_hits(model, cases, enabled)
    data = hits[:, [0, 2, 3, 5, 6]]
    out: dict[str, Any] = {"regions": len(data), "renders": len(cases), "hits": data.tolist()}
    rng = np.random.default_rng(0)
    for j, name in enumerate(("top1", "top5", "substance_head", "substance_mass"), start=1):
        out[name] = interval(data[:, j], data[:, 0].astype(int), rng)
    return out


def substance_arm(settings: Any, store: BlobStore, spec: str, cases: list, substance_of: dict[int, str]) -> dict:
    """Part substance top-1 of a substance network on the photo-like cases (the stage's own reading).

    `spec`: "unet" (the newest from-scratch segmentation network on the collection) or a substance
    preset name on a backbone ("backbone"), trained here on the bootstrap round.
    """
    from photoshape_flow.classify.substance_configs import get_config as substance_config
    from photoshape_flow.networks.classifiers import load_substance_network
    from photoshape_flow.recognition.bn_prior import substance_readings
    from photoshape_flow.recognition.substances import train_recogniser

    started = time.perf_counter()
    if spec == "unet":
        with session_scope(settings.resolved_database_url) as session:
            row = session.scalars(sa.select(m.Classifier).where(m.Classifier.kind == "substance")
                                  .order_by(m.Classifier.id)).first()
            network, network_id = load_substance_network(row, store, "cpu"), row.id
            size = read_side_of(row.config) or 128
    else:
        network_id, network, _info = train_recogniser(settings, substance_config(spec, seed=settings.seed))
        size = 128
    probs, truth, group = substance_readings(network, size, cases, substance_of, None)
    hits = (probs.argmax(1) == truth).astype(float)
    rows = np.stack([group, hits, hits, hits, hits], 1)
    return {"spec": spec, "classifier": network_id, "train_seconds": round(time.perf_counter() - started, 1),
            "regions": len(hits), "substance_part": round(float(hits.mean()), 3), "hits": rows.tolist()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", action="append", default=[], help="name=preset[:field=value,...]")
    parser.add_argument("--substance", action="append", default=[], help="name=unet|<substance preset>")
    parser.add_argument("--renders", type=int, default=100, help="validation renders made photo-like")
    parser.add_argument("--out", default=None, help="default: <data root>/experiments/backbone_recognition/arms.json")
    args = parser.parse_args()
    settings = get_settings()
    set_torch_threads(settings.torch_threads)
    store = BlobStore(settings.blob_root)
    with session_scope(settings.resolved_database_url) as session:
        cases = photo_cases(session, store, settings, args.renders)
        enabled = set(material_set(session).ids)
        substance_of = dict(session.execute(sa.select(m.Material.id, m.Material.substance)).all())
    results: dict[str, Any] = {}
    for arm in args.substance:
        name, _, spec = arm.partition("=")
        results[name] = substance_arm(settings, store, spec, cases, substance_of)
        print(name, json.dumps({k: v for k, v in results[name].items() if k != "hits"}), flush=True)
    for arm in args.arm:
        name, _, spec = arm.partition("=")
        config = arm_config(spec)
        started = time.perf_counter()
        classifier_id = run_training(config, name=f"exp-{name}-{config.architecture}", settings=settings)
        seconds = time.perf_counter() - started
        _row, model = load_material_classifier(classifier_id, settings)
        results[name] = {"spec": spec, "classifier": classifier_id, "train_seconds": round(seconds, 1),
                         **score(model, cases, enabled)}
        print(name, json.dumps({k: v for k, v in results[name].items() if k != "hits"}), flush=True)
    out = Path(args.out) if args.out else results_dir(settings, "backbone_recognition") / "arms.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
