#!/usr/bin/python3
"""Renders a raster with QGIS, headless (python3-qgis): QGIS must open it as a valid layer in its CRS.

    qgis_render.py RASTER OUT.png

Writes OUT.png (800 px wide, the layer over a white background) and prints the layer's CRS, size and bands as JSON.
Exit 1 when QGIS cannot open the raster, 2 on bad arguments or without python3-qgis.
"""
import json
import os
import sys

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
if "XDG_RUNTIME_DIR" not in os.environ:  # Qt wants a private one
    import tempfile
    os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="qgis-runtime-")
try:
    from qgis.core import QgsApplication, QgsMapRendererSequentialJob, QgsMapSettings, QgsRasterLayer
    from qgis.PyQt.QtCore import QSize
    from qgis.PyQt.QtGui import QColor
except ImportError as e:
    print(f"python3-qgis is missing: {e}", file=sys.stderr)
    sys.exit(2)

if len(sys.argv) != 3:
    print(__doc__, file=sys.stderr)
    sys.exit(2)
raster, out_png = sys.argv[1], sys.argv[2]
app = QgsApplication([], False)
app.initQgis()
layer = QgsRasterLayer(raster, "layer")
if not layer.isValid():
    print(f"QGIS cannot open {raster}: {layer.error().summary()}", file=sys.stderr)
    sys.exit(1)
extent = layer.extent()
settings = QgsMapSettings()
settings.setLayers([layer])
settings.setDestinationCrs(layer.crs())
settings.setExtent(extent)
width = 800
settings.setOutputSize(QSize(width, max(1, int(width * extent.height() / max(extent.width(), 1e-9)))))
settings.setBackgroundColor(QColor(255, 255, 255))
job = QgsMapRendererSequentialJob(settings)
job.start()
job.waitForFinished()
ok = job.renderedImage().save(out_png)
print(json.dumps({"crs": layer.crs().authid(), "width": layer.width(), "height": layer.height(),
                  "bands": layer.bandCount(), "saved": bool(ok)}))
sys.stdout.flush()
# exitQgis() crashes on teardown in Debian 12's QGIS 3.22; the work is done and saved, so leave without it.
os._exit(0 if ok else 1)
