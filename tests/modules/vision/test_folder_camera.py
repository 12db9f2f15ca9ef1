"""FolderCamera reads PGM/PPM/NPY files written by the test, in name order, paced by an injected clock."""

import numpy as np
import pytest

from modules.vision.folder_camera import FolderCamera, load_image
from modules.vision.pnm import encode_pnm


class ManualClock:
    """Test clock: ``sleep`` advances time instead of waiting."""

    def __init__(self, start=100.0):
        self.now = start
        self.sleeps = []

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.sleeps.append(seconds)
        self.now += seconds


def images(n):
    rng = np.random.default_rng(n)
    return [rng.integers(0, 256, size=(6, 8, 3) if k % 2 else (6, 8), dtype=np.uint8) for k in range(n)]


def write_mixed(folder, imgs):
    """Alternate .pgm (grey) / .ppm (RGB) / .npy, names chosen so name order == index order."""
    for k, img in enumerate(imgs):
        if k % 3 == 2:
            np.save(folder / f"f{k:03d}.npy", img)
        else:
            suffix = ".ppm" if img.ndim == 3 else ".pgm"
            (folder / f"f{k:03d}{suffix}").write_bytes(encode_pnm(img))


def test_reads_every_format_in_name_order(tmp_path):
    imgs = images(6)
    write_mixed(tmp_path, imgs)
    (tmp_path / "notes.txt").write_text("not an image")
    with FolderCamera(tmp_path) as cam:
        frames = [cam.read() for _ in range(6)]
        assert cam.read() is None
    for k, (frame, img) in enumerate(zip(frames, imgs, strict=True)):
        assert frame.seq == k
        np.testing.assert_array_equal(frame.image, img)


def test_rate_paces_frames_on_the_injected_clock(tmp_path):
    write_mixed(tmp_path, images(4))
    clock = ManualClock()
    cam = FolderCamera(tmp_path, rate_hz=10.0, clock=clock, sleep=clock.sleep)
    stamps = [cam.read().timestamp for _ in range(4)]
    assert stamps == pytest.approx([100.0, 100.1, 100.2, 100.3])
    assert len(clock.sleeps) == 3
    cam.close()


def test_late_reader_is_not_made_to_wait(tmp_path):
    write_mixed(tmp_path, images(3))
    clock = ManualClock()
    cam = FolderCamera(tmp_path, rate_hz=10.0, clock=clock, sleep=clock.sleep)
    cam.read()
    clock.now += 1.0  # the consumer was slow
    assert cam.read().timestamp == pytest.approx(101.0)
    assert clock.sleeps == []


def test_loop_restarts_from_the_first_file(tmp_path):
    imgs = images(2)
    write_mixed(tmp_path, imgs)
    cam = FolderCamera(tmp_path, loop=True)
    seen = [cam.read() for _ in range(5)]
    assert [f.seq for f in seen] == [0, 1, 2, 3, 4]
    np.testing.assert_array_equal(seen[4].image, imgs[0])
    np.testing.assert_array_equal(seen[3].image, imgs[1])


def test_corrupt_files_are_dropped_counted_and_skipped(tmp_path):
    imgs = images(3)
    write_mixed(tmp_path, imgs)
    (tmp_path / "f000a.pgm").write_bytes(b"P5\n8 6\n255\n" + b"\x00" * 10)  # truncated raster
    np.save(tmp_path / "f001a.npy", np.zeros((4, 4), dtype=np.float64))  # wrong dtype
    (tmp_path / "f001b.npy").write_bytes(b"garbage")
    cam = FolderCamera(tmp_path)
    got = [cam.read() for _ in range(3)]
    assert cam.read() is None
    for frame, img in zip(got, imgs, strict=True):
        np.testing.assert_array_equal(frame.image, img)
    assert cam.dropped == 3
    assert "f001b.npy" in cam.last_error


def test_looping_over_only_corrupt_files_ends_instead_of_spinning(tmp_path):
    (tmp_path / "bad.ppm").write_bytes(b"P3\n1 1\n255\n0 0 0\n")
    cam = FolderCamera(tmp_path, loop=True)
    assert cam.read() is None
    assert cam.dropped == 1


def test_npy_single_channel_is_squeezed(tmp_path):
    np.save(tmp_path / "a.npy", np.full((3, 4, 1), 7, dtype=np.uint8))
    img = load_image(tmp_path / "a.npy")
    assert img.shape == (3, 4) and int(img[0, 0]) == 7


def test_close_is_idempotent_and_read_after_close_is_none(tmp_path):
    write_mixed(tmp_path, images(2))
    cam = FolderCamera(tmp_path)
    cam.close()
    cam.close()
    assert cam.closed and cam.read() is None


def test_folder_errors_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        FolderCamera(tmp_path / "missing")
    with pytest.raises(ValueError, match="holds no"):
        FolderCamera(tmp_path)
    write_mixed(tmp_path, images(1))
    with pytest.raises(ValueError, match="rate_hz"):
        FolderCamera(tmp_path, rate_hz=0.0)
