"""Crash pulses: the signal type, SAE J211 CFC filtering, integration, resampling, file IO.

Convention (see :mod:`marlcrash.pulse.signal`): SI inside; velocity is the
vehicle's forward speed and acceleration its derivative, so a frontal crash
pulse is negative.
"""

from marlcrash.pulse.cfc import CFC_CLASSES, cfc_coefficients, cfc_filter, cfc_filter_torch, cfc_matrix, f_h, f_n
from marlcrash.pulse.io import (
    mme_channels,
    plot_pulse,
    processed_pulse,
    pulse_figures,
    pulse_summary,
    read_csv,
    read_mme,
    read_pulse,
    write_csv,
    write_mme,
)
from marlcrash.pulse.signal import (
    SURROGATE_RATE_HZ,
    Onset,
    Pulse,
    compared_velocity,
    compared_window,
    filter_pulse,
    find_onset,
    find_time_zero,
    from_rearward_x,
    integrate,
    integrate_torch,
    margin_samples,
    prepare_velocity,
    remove_zero_offset,
    resample,
    sampled_acceleration,
    shift_time,
    without_zero_offset,
)

__all__ = [
    "CFC_CLASSES",
    "SURROGATE_RATE_HZ",
    "Onset",
    "Pulse",
    "cfc_coefficients",
    "cfc_filter",
    "cfc_filter_torch",
    "cfc_matrix",
    "compared_velocity",
    "compared_window",
    "f_h",
    "f_n",
    "filter_pulse",
    "find_onset",
    "find_time_zero",
    "from_rearward_x",
    "integrate",
    "integrate_torch",
    "margin_samples",
    "mme_channels",
    "plot_pulse",
    "prepare_velocity",
    "processed_pulse",
    "pulse_figures",
    "pulse_summary",
    "read_csv",
    "read_mme",
    "read_pulse",
    "remove_zero_offset",
    "resample",
    "sampled_acceleration",
    "shift_time",
    "without_zero_offset",
    "write_csv",
    "write_mme",
]
