"""A typo in ``processing.parameters`` (ChainParameters.from_mapping) is an error that names
the key and suggests the near miss; it never silently runs with the default."""

from __future__ import annotations

import pytest

from processing.chain import ChainParameters


def test_typo_names_the_key_and_suggests_the_known_one() -> None:
    with pytest.raises(ValueError) as err:
        ChainParameters.from_mapping({"alhpa": 0.1, "beta": 0.2})
    msg = str(err.value)
    assert "'alhpa' (did you mean 'alpha'?)" in msg
    assert msg.startswith("unknown processing parameter")


def test_every_unknown_key_is_named_far_misses_without_a_guess() -> None:
    with pytest.raises(ValueError) as err:
        ChainParameters.from_mapping({"zzz_unrelated": 1, "alpah": 0.1})
    msg = str(err.value)
    assert "'alpah' (did you mean 'alpha'?)" in msg
    assert "'zzz_unrelated';" in msg or "'zzz_unrelated'," in msg
    assert "did you mean" not in msg.split("'zzz_unrelated'")[1].split(";")[0]


def test_known_keys_are_taken() -> None:
    p = ChainParameters.from_mapping({"alpha": 0.07})
    assert p.alpha == 0.07 and p.beta == ChainParameters().beta


def test_flow_drop_blanked_is_off_by_default_and_takes_only_a_boolean() -> None:
    assert ChainParameters().flow_drop_blanked is False
    assert ChainParameters.from_mapping({"flow_drop_blanked": True}).flow_drop_blanked
    with pytest.raises(ValueError, match="flow_drop_blanked must be true or false"):
        ChainParameters.from_mapping({"flow_drop_blanked": "yes"})
