"""Which body a run tracks with (``gltrack track --body``): one place resolves the choice.

``dataset``
    The body record in the dataset's ``meta.json`` (:func:`gltrack.body.model.body_from_meta`).
    For synthetic data this is the true skeleton the data was made with: an oracle, for
    ablations. A dataset without a record gets the default body.
``FILE.json``
    A body record (:func:`gltrack.body.model.body_from_record`): the ``body.json`` of an earlier
    run's results folder (or the folder itself), or one written by hand.

The runner writes the returned record to the results folder's ``body.json``, from which export,
render and eval rebuild the body.
"""
from __future__ import annotations

from pathlib import Path

from gltrack.body.model import BodyModel, body_from_meta, body_record
from gltrack.data.results import load_body_record

#: The named choices of ``--body`` (anything else is a body file).
CHOICES = ("dataset",)


def resolve_body(spec: str, dataset, preset: str | None) -> tuple[BodyModel, dict]:
    """The body a run tracks with, and its record for ``body.json``.

    Parameters
    ----------
    spec : str
        ``"dataset"`` or the path of a body file (or of a results folder holding ``body.json``).
    dataset : gltrack.data.dataset.Dataset
        The dataset being tracked (its ``meta.json`` body record for ``"dataset"``).
    preset : str, optional
        DOF preset overriding the recorded one (``--dof``).

    Returns
    -------
    body : BodyModel
    record : dict
        :func:`gltrack.body.model.body_record` of ``body``, ``source`` "dataset" or "file".

    Raises
    ------
    ValueError
        ``spec`` names no file, or the record is invalid (naming the file and the field).
    """
    if spec == "dataset":
        body = body_from_meta(dataset.body, preset, where=str(Path(dataset.path) / "meta.json"))
        return body, body_record(body, "dataset")
    path = Path(spec)
    if not path.exists():
        raise ValueError(f"--body: {spec!r} is neither {' nor '.join(CHOICES)} nor a body file")
    body, _ = load_body_record(path)
    if preset is not None and preset != body.dofs.preset:
        body = body.with_preset(preset)
    return body, body_record(body, "file")
