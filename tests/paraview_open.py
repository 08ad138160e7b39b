"""Opens files as ParaView's File > Open does (paraview.simple.OpenDataFile picks the reader: the
one ParaView uses by itself) and prints what that reader gives at the first time step:

    pvpython tests/paraview_open.py FILE...

Per file, words `key=value`:
  file=PATH reader=NAME readers=A,B points=P cells=C times=T blocks=N
      NAME: the reader ParaView picked (its proxy's XML name, e.g. XdmfReader); readers: every
      reader ParaView offers for the file (File > Open asks which when there are several);
      points and cells summed over the blocks; blocks: the leaf data sets.
  block file=PATH reader=NAME name=BLOCK points=P cells=C
      one line per leaf data set, BLOCK being the name the Multiblock Inspector shows (the
      composite data set's NAME metadata; `-` where the block has none, as a piece of a
      partitioned data set has not).
Exit status 1 when ParaView has no reader for a file or the reader gives nothing.
"""
import os
import sys

from paraview import servermanager
from paraview.simple import OpenDataFile
from vtkmodules.vtkCommonDataModel import vtkCompositeDataSet


def offered_readers(path):
    """The names of every reader ParaView offers for `path`."""
    factory = servermanager.vtkSMProxyManager.GetProxyManager().GetReaderFactory()
    if factory.GetNumberOfRegisteredPrototypes() == 0:
        factory.UpdateAvailableReaders()
    found = factory.GetReaders(path, servermanager.ActiveConnection.Session)
    # Triples: group, name, label.
    strings = [found.GetString(i) for i in range(found.GetNumberOfStrings())]
    return [strings[i + 1] for i in range(0, len(strings) - 2, 3)]


def leaves(data, name="-", found=None):
    """The leaf data sets of `data` with the name of the block each is in."""
    found = [] if found is None else found
    if data is None:
        return found
    if data.IsA("vtkMultiBlockDataSet"):
        for i in range(data.GetNumberOfBlocks()):
            meta = data.GetMetaData(i) if data.HasMetaData(i) else None
            block = meta.Get(vtkCompositeDataSet.NAME()) if meta is not None and meta.Has(vtkCompositeDataSet.NAME()) else "-"
            leaves(data.GetBlock(i), block, found)
    elif data.IsA("vtkMultiPieceDataSet"):
        for i in range(data.GetNumberOfPieces()):
            leaves(data.GetPiece(i), "-", found)
    elif data.IsA("vtkCompositeDataSet"):
        iterator = data.NewIterator()
        iterator.InitTraversal()
        while not iterator.IsDoneWithTraversal():
            found.append(("-", iterator.GetCurrentDataObject()))
            iterator.GoToNextItem()
    else:
        found.append((name, data))
    return found


def main(paths):
    for path in paths:
        path = os.path.abspath(path)  # as File > Open passes it (the Xdmf3 readers misread a bare name)
        readers = offered_readers(path)
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
        name = reader.GetXMLName()
        blocks = leaves(servermanager.Fetch(reader))
        print(f"file={path} reader={name} readers={','.join(readers) or '-'} points={info.GetNumberOfPoints()} "
              f"cells={info.GetNumberOfCells()} times={len(times)} blocks={len(blocks)}")
        for block, data in blocks:
            print(f"block file={path} reader={name} name={block.replace(' ', '_')} points={data.GetNumberOfPoints()} "
                  f"cells={data.GetNumberOfCells()}")
        if info.GetNumberOfPoints() == 0:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
