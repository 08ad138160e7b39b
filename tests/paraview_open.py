"""Opens files as ParaView's File > Open does (paraview.simple.OpenDataFile picks the reader) and
prints what the reader gives at the first time step:

    pvpython tests/paraview_open.py FILE...

One line per file: file=PATH reader=NAME points=P cells=C times=T (points and cells summed over
the blocks). Exit status 1 when ParaView has no reader for a file or the reader gives nothing.
"""
import sys

from paraview.simple import OpenDataFile


def main(paths):
    for path in paths:
        reader = OpenDataFile(path)
        if reader is None:
            print(f"paraview_open: no reader for {path}")
            return 1
        times = list(getattr(reader, "TimestepValues", None) or [])
        if times:
            reader.UpdatePipeline(times[0])
        else:
            reader.UpdatePipeline()
        info = reader.GetDataInformation()
        print(f"file={path} reader={reader.GetXMLName()} points={info.GetNumberOfPoints()} cells={info.GetNumberOfCells()} "
              f"times={len(times)}")
        if info.GetNumberOfPoints() == 0:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
