"""Every package's own errors derive from the one root the CLI catches."""

import pytest

from capture.errors import CaptureError, ConfigError
from devices.errors import DeviceError, DeviceInitError, WalkcapError
from devices.files import NotARegularFile
from inference.calibration import CalibrationError
from inference.errors import InferenceError
from tui.app import describe_error


@pytest.mark.parametrize(
    "error",
    [
        DeviceError,
        DeviceInitError,
        NotARegularFile,
        InferenceError,
        CalibrationError,
        CaptureError,
        ConfigError,
    ],
)
def test_each_package_error_is_a_walkcap_error_shown_as_its_message(error):
    assert issubclass(error, WalkcapError)
    assert describe_error(error("the port is gone")) == "the port is gone"


def test_a_path_that_is_not_a_file_is_still_an_os_error():
    assert issubclass(NotARegularFile, FileExistsError)
