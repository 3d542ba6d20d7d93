# One-time generator of SGI oracle files (run from tests/data/sgi). Pillow writes verbatim SGI,
# netpbm's pnmtosgi writes RLE; the PNGs hold the pattern.
from PIL import Image
import subprocess
W, H = 9, 6
def px(x, y):
    if y == 2:                      # a flat row: RLE repeat runs
        return (200, 100, 50, 255)
    if x >= 6 and y >= 3:           # a flat block
        return (10, 20, 30, 128)
    return ((x * 29 + y * 7) % 256, (x * 3 + y * 41) % 256, (255 - x * 19 - y * 5) % 256, (x * 31 + y * 17) % 256)
rgba = Image.new("RGBA", (W, H))
rgba.putdata([px(x, y) for y in range(H) for x in range(W)])
rgba.save("pattern_rgba.png")
rgba.save("rgba_verbatim_pillow.rgb", format="SGI")
rgb = rgba.convert("RGB")
rgb.save("pattern_rgb.png")
grey = rgb.convert("L")
grey.save("pattern_grey.png")
grey.save("grey_verbatim_pillow.rgb", format="SGI")
rgb.save("/tmp/p.ppm"); grey.save("/tmp/p.pgm")
with open("rgb_rle_netpbm.rgb", "wb") as f:
    subprocess.run(["pnmtosgi", "-rle", "/tmp/p.ppm"], stdout=f, check=True)
with open("grey_rle_netpbm.rgb", "wb") as f:
    subprocess.run(["pnmtosgi", "-rle", "/tmp/p.pgm"], stdout=f, check=True)
# 16-bit RGB, RLE: each 8-bit value v becomes v*257, so it decodes back to v.
with open("/tmp/p16.ppm", "wb") as f:
    f.write(b"P6\n%d %d\n65535\n" % (W, H))
    for r, g, b in rgb.getdata():
        for v in (r, g, b):
            f.write((v * 257).to_bytes(2, "big"))
with open("rgb16_rle_netpbm.rgb", "wb") as f:
    subprocess.run(["pnmtosgi", "-rle", "/tmp/p16.ppm"], stdout=f, check=True)
for n in ["rgb_rle_netpbm.rgb", "grey_rle_netpbm.rgb", "rgb16_rle_netpbm.rgb", "rgba_verbatim_pillow.rgb"]:
    im = Image.open(n); print(n, im.mode, im.size, open(n,"rb").read()[2:4].hex())
    ref = {"RGB": rgb, "L": grey, "RGBA": rgba}[im.mode]
    assert list(im.getdata()) == list(ref.getdata()), n
