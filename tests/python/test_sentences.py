"""NMEA-style IMU sentences ($VNYMR, $VNMAR, … with an XOR or CRC-16 checksum): fields by the known
layout with units, checksums verified (a mismatch is a bad line), other sentence types counted, a clock
prefix as time, and a sentence cut short named by line."""
import binascii
from functools import reduce

import numpy as np
import pytest

from conftest import simulated
from fluxcal.io import read_recording


def xor8(body: str) -> str:
    return f"{reduce(lambda a, b: a ^ b, body.encode(), 0):02X}"


def crc16(body: str) -> str:
    return f"{binascii.crc_hqx(body.encode(), 0):04X}"


def test_the_checksum_of_vectornavs_own_example():
    assert xor8("VNRRG,8") == "4B"  # the manual's read-register command, $VNRRG,8*4B


def mag_readings(n=200):
    return np.round(simulated(9, n=n, field_norm=0.5).readings, 4)  # gauss, as a VN-100 prints them


def test_ymr_sentences_with_a_bad_checksum_a_register_reply_and_a_cut_last_line(tmp_path):
    m = mag_readings()
    lines = ["$VNRRG,06,14*5C"]
    for x, y, z in m:
        body = f"VNYMR,+010.071,-002.267,-001.100,{x:+08.4f},{y:+08.4f},{z:+08.4f},-00.180,-00.118,-09.749," \
               "-00.000355,+00.000061,-00.000328"
        lines.append(f"${body}*{xor8(body)}")
    lines[51] = lines[51][:-2] + ("00" if lines[51][-2:] != "00" else "01")  # a flipped bit in transit
    path = tmp_path / "vn100.txt"
    path.write_text("\n".join(lines) + "\n$VNYMR,+010.0")
    with pytest.raises(ValueError, match=r"vn100.txt, line 52: checksum .. does not match the sentence .*--bad-lines skip"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    np.testing.assert_array_equal(rec.samples(), np.delete(m, 50, axis=0))
    assert rec.field_units() == "G" and rec.units["accel_x"] == "m/s^2" and rec.columns["yaw"][0] == 10.071
    assert rec.metadata["other_sentences"] == "VNRRG 1" and rec.acceleration().shape == (len(m) - 1, 3)
    assert "202 (1 fields, a VNYMR sentence has 12 (cut short?))" in rec.metadata["skipped_lines"]


def test_mar_sentences_with_crc16_and_a_serial_monitors_clock(tmp_path):
    m = mag_readings(50)
    lines = []
    for k, (x, y, z) in enumerate(m):
        body = f"VNMAR,{x:+08.4f},{y:+08.4f},{z:+08.4f},+00.1,-00.2,-09.8,+0.01,+0.02,-0.03"
        lines.append(f"10:00:{k * 0.05:06.3f} -> ${body}*{crc16(body)}")
    path = tmp_path / "mar.log"
    path.write_text("\n".join(lines) + "\n")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    np.testing.assert_allclose(rec.time(), np.arange(len(m)) * 0.05, atol=1e-9)
    bad = lines[10].replace("+0.01", "+0.02")  # the fields changed, the CRC not
    path.write_text("\n".join(lines[:10] + [bad] + lines[11:]) + "\n")
    with pytest.raises(ValueError, match=r"mar.log, line 11: checksum [0-9A-F]{4} does not match"):
        read_recording(path)


def test_an_unknown_sentence_type_is_columns_by_position(tmp_path):
    path = tmp_path / "pchrs.txt"
    body = [f"PXYZ,{k},{0.1 * k:.1f},{-0.2:.1f},{0.3:.1f}" for k in range(5)]
    path.write_text("".join(f"${b}*{xor8(b)}\n" for b in body))
    rec = read_recording(path, columns="PXYZ_2,PXYZ_3,PXYZ_4")
    assert rec.samples().shape == (5, 3) and rec.metadata["layout"] == "PXYZ sentences"
    with pytest.raises(ValueError, match=r"no magnetometer columns .*columns are: PXYZ_1, PXYZ_2, PXYZ_3, PXYZ_4"):
        read_recording(path).samples()


def test_a_sentence_with_extra_fields_is_a_bad_line(tmp_path):
    body = "VNMAG,+0.2000,-0.1000,+0.4000"
    extra = "VNMAG,+0.2000,-0.1000,+0.4000,+0.5"
    path = tmp_path / "mag.txt"
    path.write_text(f"${body}*{xor8(body)}\n${extra}*{xor8(extra)}\n${body},T12AF*{xor8(body + ',T12AF')}\n")
    with pytest.raises(ValueError, match=r"line 2: 4 fields, a VNMAG sentence has 3 \(two sentences run together\?\)"):
        read_recording(path)
    assert len(read_recording(path, bad_lines="skip")) == 2  # VectorNav's appended T… counter is not extra


def test_a_sentence_without_its_checksum_among_checksummed_ones_is_a_bad_line(tmp_path):
    """A VNMAG cut before its '*hh' (or with it lost) had been read as a good reading; a file of sentences that
    carry none at all is read and says they are unverified."""
    m = mag_readings(30)
    bodies = [f"VNMAG,{x:+08.4f},{y:+08.4f},{z:+08.4f}" for x, y, z in m]
    path = tmp_path / "vnmag.txt"
    path.write_text("\n".join(f"${b}*{xor8(b)}" for b in bodies[:-1]) + f"\n${bodies[-1]}")
    with pytest.raises(ValueError, match=r"vnmag.txt, line 30: no checksum \(none\), where the file's other VNMAG "
                                         r"sentences carry one: cut or garbled"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    np.testing.assert_array_equal(rec.samples(), m[:-1])
    assert "checksums" not in rec.metadata
    path.write_text("\n".join(f"${b}" for b in bodies) + "\n")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.metadata["checksums"].startswith("none: the VNMAG sentences carry no checksum")
