#!/usr/bin/python3
"""Opens files heartsim writes with VTK's own readers, as ParaView does, and prints what they hold.

    /usr/bin/python3 tests/vtk_open.py FILE...

One line per file (per block for an XDMF description), words `key=value`:
  .xmf2 .xdmf  with every XDMF reader this VTK has (vtkXdmfReader: ParaView's "XDMF Reader";
         vtkXdmf3Reader: "Xdmf3 Reader"):  reader=NAME times=T  then per time step shown
         (the first, and the last when T > 1) and per block:
         block reader=NAME time=0|1 (first|last) name=NAME points=P cells=C bounds=x0,x1,y0,y1,z0,z1 arrays=a,b
  .vtp .stl .obj .ply   file=PATH points=P cells=C open_edges=E (boundary + non-manifold edges,
         vtkFeatureEdges) bounds=...
Exit status: 0 when every file opened, 1 when a reader failed, 3 when this VTK has no reader
for a given kind (tests skip then). Needs VTK's Python module (python3-paraview on Debian 12, whose
VTK has the XDMF readers; python3-vtk9's has none).
"""
import os
import sys

try:
    import vtk
except ImportError as error:
    print(f"vtk_open: no VTK Python module ({error})")
    sys.exit(3)


def xdmf_readers():
    readers = []
    for module, name in (("vtkmodules.vtkIOXdmf2", "vtkXdmfReader"), ("vtkmodules.vtkIOXdmf3", "vtkXdmf3Reader")):
        try:
            readers.append((name, getattr(__import__(module, fromlist=[name]), name)))
        except (ImportError, AttributeError):
            pass
    return readers


def bounds_text(data):
    return ",".join(f"{b:.17g}" for b in data.GetBounds())


def leaves(data, name="", found=None):
    """The leaf data sets of a composite data set with their block names."""
    found = [] if found is None else found
    if data is None:
        return found
    if data.IsA("vtkMultiBlockDataSet"):
        for i in range(data.GetNumberOfBlocks()):
            meta = data.GetMetaData(i) if data.HasMetaData(i) else None
            block = meta.Get(vtk.vtkCompositeDataSet.NAME()) if meta is not None and meta.Has(vtk.vtkCompositeDataSet.NAME()) else str(i)
            leaves(data.GetBlock(i), block, found)
    elif data.IsA("vtkCompositeDataSet"):
        it = data.NewIterator()
        it.InitTraversal()
        while not it.IsDoneWithTraversal():
            found.append((str(it.GetCurrentFlatIndex()), it.GetCurrentDataObject()))
            it.GoToNextItem()
    else:
        found.append((name, data))
    return found


def open_xdmf(path):
    readers = xdmf_readers()
    if not readers:
        print(f"vtk_open: this VTK ({vtk.vtkVersion.GetVTKVersion()}) has no XDMF reader (vtkIOXdmf2/vtkIOXdmf3)")
        return 3
    for name, cls in readers:
        reader = cls()
        reader.SetFileName(os.path.abspath(path))  # as ParaView passes it (Xdmf3 misreads a bare name)
        reader.UpdateInformation()
        info = reader.GetOutputInformation(0)
        key = vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS()
        times = list(info.Get(key)) if info.Has(key) else []
        print(f"reader={name} times={len(times)}" + (f" first={times[0]:.17g} last={times[-1]:.17g}" if times else ""))
        indices = [0] if len(times) <= 1 else [0, len(times) - 1]
        for label, index in enumerate(indices):
            if times:
                reader.UpdateTimeStep(times[index])
            else:
                reader.Update()
            if reader.GetErrorCode() != 0:
                print(f"vtk_open: {name} failed on {path}")
                return 1
            output = reader.GetOutputDataObject(0)
            blocks = leaves(output)
            if not blocks:
                print(f"vtk_open: {name} read no data set from {path}")
                return 1
            for block, data in blocks:
                if data is None:
                    continue
                arrays = [data.GetPointData().GetArrayName(i) for i in range(data.GetPointData().GetNumberOfArrays())]
                print(f"block reader={name} time={label} name={block} points={data.GetNumberOfPoints()} "
                      f"cells={data.GetNumberOfCells()} bounds={bounds_text(data)} arrays={','.join(arrays)}")
    return 0


def open_mesh(path):
    extension = os.path.splitext(path)[1].lower()
    reader = {".vtp": vtk.vtkXMLPolyDataReader, ".stl": vtk.vtkSTLReader, ".obj": vtk.vtkOBJReader,
              ".ply": vtk.vtkPLYReader}[extension]()
    reader.SetFileName(path)
    if extension == ".stl":
        reader.MergingOn()  # STL repeats each corner per facet; merged, the mesh's own vertices
    reader.Update()
    data = reader.GetOutput()
    if reader.GetErrorCode() != 0 or data is None or data.GetNumberOfCells() == 0:
        print(f"vtk_open: {type(reader).__name__} read nothing from {path}")
        return 1
    edges = vtk.vtkFeatureEdges()
    edges.SetInputData(data)
    edges.BoundaryEdgesOn()
    edges.NonManifoldEdgesOn()
    edges.FeatureEdgesOff()
    edges.ManifoldEdgesOff()
    edges.Update()
    print(f"file={path} points={data.GetNumberOfPoints()} cells={data.GetNumberOfCells()} "
          f"open_edges={edges.GetOutput().GetNumberOfCells()} bounds={bounds_text(data)}")
    return 0


def main(paths):
    status = 0
    for path in paths:
        if not os.path.exists(path):
            print(f"vtk_open: {path}: no such file")
            return 1
        result = open_xdmf(path) if path.lower().endswith((".xdmf", ".xmf", ".xmf2", ".xdmf2")) else open_mesh(path)
        status = 1 if 1 in (status, result) else max(status, result)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
