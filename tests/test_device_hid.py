"""`HidDevice` report parsing and force reports.

There is no HID haptic device on this machine: the real hidapi is exercised where it can run
(opening a device that is not there fails cleanly); report traffic goes through `FakeHid`, an
object with the `hid.device` methods, standing in for the USB device only.
"""

import json
import struct

import numpy as np
import pytest

from bsjax.device import HapticDevice, HidDevice, HidField, HidLayout, SimulatedDevice, Workspace
from bsjax.device._hid import force_report, parse_report


class FakeHid:
    """`hid.device`-like: queued input reports, recorded output reports."""

    def __init__(self):
        self.queue, self.written, self.opened, self.fail = [], [], None, False

    def open(self, vid, pid):
        self.opened = (vid, pid)

    def open_path(self, path):
        self.opened = path

    def set_nonblocking(self, flag):
        self.nonblocking = flag

    def read(self, n):
        if self.fail:
            raise OSError("read error")
        return list(self.queue.pop(0)) if self.queue else []

    def write(self, data):
        self.written.append(bytes(data))
        return len(data)

    def close(self):
        self.opened = None


def generic_report(seq, position_m, quat=(1.0, 0.0, 0.0, 0.0), buttons=0, report_id=1):
    pos = [int(round(p / 1e-4)) for p in position_m]
    q = [int(round(c * 32767)) for c in quat]
    return struct.pack("<B3h4hBH2x", report_id, *pos, *q, buttons, seq)


def test_generic_layout_parses_positions_orientation_buttons_sequence():
    layout = HidLayout.generic(0x1234, 0x5678)
    parsed = parse_report(layout, generic_report(7, (0.01, -0.02, 0.0305), (0.0, 1.0, 0.0, 0.0), buttons=1))
    position, orientation, buttons, stamp, seq = parsed
    np.testing.assert_allclose(position, (0.01, -0.02, 0.0305), atol=1e-9)
    np.testing.assert_allclose(orientation, (0.0, 1.0, 0.0, 0.0))
    assert buttons == 1 and seq == 7 and stamp is None
    assert parse_report(layout, generic_report(1, (0, 0, 0))[:10]) is None  # short
    assert parse_report(layout, generic_report(1, (0, 0, 0), report_id=3)) is None  # other report


def test_device_reads_newest_drops_stale_and_short_reports_writes_forces():
    fake = FakeHid()
    dev = HidDevice(HidLayout.generic(0x1234, 0x5678), device=fake, workspace=Workspace(scale=10.0))
    assert isinstance(dev, HapticDevice) and isinstance(SimulatedDevice(), HapticDevice)
    assert fake.opened == (0x1234, 0x5678) and fake.nonblocking == 1
    fake.queue += [
        generic_report(5, (0.01, 0, 0)),
        generic_report(6, (0.02, 0, 0)),
        b"\x01\x02",
        generic_report(4, (0.05, 0, 0)),
    ]
    sample = dev.read()
    assert sample.sequence == 6 and sample.position[0] == pytest.approx(0.2)
    assert dev.counters == {"frames": 2, "malformed": 1, "out_of_order": 1}
    dev.write((1.0, -0.5, 100.0))  # 100 N saturates the int16 mN field
    report = fake.written[-1]
    assert report[0] == 2 and struct.unpack_from("<3h", report, 1) == (1000, -500, 32767)
    dev.close()
    assert struct.unpack_from("<3h", fake.written[-1], 1) == (0, 0, 0) and fake.opened is None


def test_device_loss_and_reconnect():
    fake = FakeHid()
    dev = HidDevice(HidLayout.generic(1, 2), device=fake, reconnect_interval=0.0)
    fake.queue.append(generic_report(1, (0.0, 0.0, 0.01)))
    first = dev.read()
    fake.fail = True
    assert dev.read() is first and dev.counters["disconnects"] == 1
    fake.fail = False
    fake.queue.append(generic_report(0, (0.0, 0.0, 0.02)))  # a re-plugged device restarts at 0
    assert dev.read().position[2] == pytest.approx(0.02) and dev.counters["reconnects"] == 1


def test_layout_from_json_and_validation():
    spec = {
        "vendor_id": 1,
        "product_id": 2,
        "report_length": 13,
        "position": [{"offset": 0, "fmt": "<f"}, {"offset": 4, "fmt": "<f"}, {"offset": 8, "fmt": "<f"}],
        "buttons": {"offset": 12, "fmt": "B"},
        "force": [{"offset": 1, "fmt": "<f"}, {"offset": 5, "fmt": "<f"}, {"offset": 9, "fmt": "<f"}],
        "force_length": 13,
    }
    layout = HidLayout.from_dict(json.loads(json.dumps(spec)))
    position, orientation, buttons, _, seq = parse_report(layout, struct.pack("<3fB", 0.1, 0.2, 0.3, 3))
    np.testing.assert_allclose(position, (0.1, 0.2, 0.3), rtol=1e-6)
    assert buttons == 3 and seq is None and orientation[0] == 1.0
    assert struct.unpack_from("<3f", force_report(layout, (1, 2, 3)), 1) == (1.0, 2.0, 3.0)
    with pytest.raises(ValueError, match="report_length"):
        HidLayout.from_dict({**spec, "report_length": 8})
    with pytest.raises(ValueError, match="fmt"):
        HidField(0, "<hh")
    with pytest.raises(ValueError, match="position"):
        HidLayout.from_dict({**spec, "position": spec["position"][:2]})


def test_real_hidapi_reports_a_missing_device():
    with pytest.raises(OSError):
        HidDevice(HidLayout.generic(0xFFFF, 0xFFFE))


def float_layout():
    f = [{"offset": 4 * k, "fmt": "<f"} for k in range(3)]
    return HidLayout.from_dict(
        {
            "vendor_id": 1,
            "product_id": 2,
            "report_length": 16,
            "position": f,
            "buttons": {"offset": 12, "fmt": "<f"},
            "force": [{"offset": 1 + 4 * k, "fmt": "<f"} for k in range(3)],
            "force_length": 13,
        }
    )


def test_non_finite_and_out_of_reach_reports_are_dropped_and_counted():
    fake = FakeHid()
    dev = HidDevice(float_layout(), device=fake, workspace=Workspace(reach=1.0))
    fake.queue.append(struct.pack("<4f", 0.1, 0.0, 0.0, 1.0))
    first = dev.read()
    assert first.position[0] == pytest.approx(0.1) and first.pressed
    fake.queue += [
        struct.pack("<4f", float("nan"), 0.0, 0.0, 0.0),
        struct.pack("<4f", 0.0, float("inf"), 0.0, 0.0),
        struct.pack("<4f", 0.0, 0.0, 1e30, 0.0),  # finite, out of reach
        struct.pack("<4f", 0.0, 0.0, 0.0, float("nan")),  # NaN buttons: not an int
    ]
    assert dev.read() is first  # nothing new: the last good sample ages (the watchdog acts)
    assert dev.counters == {"frames": 1, "bad_pose": 3, "malformed": 1}
    assert parse_report(float_layout(), struct.pack("<4f", 0.0, 0.0, 0.0, float("inf"))) is None
    assert parse_report(float_layout(), "not bytes") is None


def _spec(**changes):
    f = [{"offset": 4 * k, "fmt": "<f"} for k in range(3)]
    spec = {
        "vendor_id": 1,
        "product_id": 2,
        "report_length": 12,
        "position": f,
        "force": f,
        "force_length": 12,
    }
    return {**spec, **changes}


@pytest.mark.parametrize(
    ("make", "error", "name"),
    [
        (lambda: HidField("a"), TypeError, "offset"),
        (lambda: HidField(-1), ValueError, "offset"),
        (lambda: HidField(0, 5), TypeError, "fmt"),
        (lambda: HidField(0, "<f", "1"), TypeError, "scale"),
        (lambda: HidField(0, "<f", float("inf")), ValueError, "scale"),
        (lambda: HidLayout.generic(70000, 1), ValueError, "vendor_id"),
        (lambda: HidLayout.from_dict(_spec(colour=1)), ValueError, "colour"),
        (lambda: HidLayout.from_dict({"vendor_id": 1}), ValueError, "force"),
        (lambda: HidLayout.from_dict(_spec(position={"offset": 0})), TypeError, "position"),
        (lambda: HidLayout.from_dict(_spec(position=[{"off": 0}] * 3)), ValueError, "position"),
        (lambda: HidLayout.from_dict(_spec(report_id=300)), ValueError, "report_id"),
        (lambda: HidLayout.from_dict(_spec(sequence_bits=2.5)), TypeError, "sequence_bits"),
        (lambda: HidLayout.from_dict(_spec(buttons=7)), TypeError, "buttons"),
        (
            lambda: HidDevice(HidLayout.from_dict(_spec()), device=FakeHid(), timeout=-1.0),
            ValueError,
            "timeout",
        ),
    ],
)
def test_layout_errors_name_the_key(make, error, name):
    with pytest.raises(error, match=f"^{name}: expected"):
        make()
