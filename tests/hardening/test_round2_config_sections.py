"""Bad inputs, second round (issue 20), class 2: unknown keys in the config sections added since the first round
([grid] snr_bd, [focus], [fixed], [channels]) are reported, never ignored.
"""

from __future__ import annotations

import pytest

E = ["--design", "end_to_end_paper"]


# class 2: config sections added since the first round: a typo is reported, never ignored
@pytest.mark.parametrize("name, match", [("typo.toml", "snr_bd"), ("focus_typo.toml", "criteron"),
                                         ("fixed_typo.toml", "Q_frnt"), ("channels_typo.toml", "spectrm")])
def test_unknown_keys_in_config_sections_are_reported(name, match, files, refused):
    refused(["sweep", name, "--out", "a.nc"], match, files)
