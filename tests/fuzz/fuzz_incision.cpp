// libFuzzer target: the detailed mesh opened along swept surfaces (libmodel/surgery/incision.h
// open_along), as heartsim opens it along a scalpel's strokes, on a closed box 12 × 12 × 8 mm
// meshed in 0.7 mm squares. The input is one or two strokes: a byte for the poses (2 to 6), then
// per pose the blade's tip and end, six coordinates of two bytes each over −4 to 16 mm (a blade
// in the air, through a face, inside the box, along a face, folded back on itself). After each
// stroke the mesh must be a closed, consistently oriented 2-manifold with finite positions, or,
// where open_along refused, exactly as it was; open_along must never throw.
#include "fuzz_support.h"

#include "libmodel/surgery/incision.h"
#include "tests/box_mesh.h"


namespace {

using namespace heartsim;

const IncisionMesh& box() {
    static const IncisionMesh made = [] {
        const test::BoxMesh box = test::box_mesh({0, 0, 0}, {12, 12, 8}, 0.7);
        return incision_mesh(box.positions, {}, box.triangles);
    }();
    return made;
}

/// The next stroke's strip from the input, or none when the input has run out.
bool next_strip(const std::uint8_t*& data, std::size_t& size, CutSurface& strip) {
    if (size < 1) return false;
    const int poses = 2 + data[0] % 5;
    ++data, --size;
    if (size < std::size_t(poses) * 12) return false;
    auto coordinate = [&] {
        const double value = -4.0 + 20.0 * double(data[0] | (data[1] << 8)) / 65535.0;
        data += 2, size -= 2;
        return value;
    };
    strip = {};
    for (int k = 0; k < poses; ++k)
        for (int end = 0; end < 2; ++end) {
            const double x = coordinate(), y = coordinate(), z = coordinate();
            strip.points.emplace_back(x, y, z);
        }
    for (std::int32_t a = 0; a + 1 < poses; ++a) {
        const std::int32_t b = a + 1;
        strip.triangles.push_back({2 * a, 2 * a + 1, 2 * b + 1});
        strip.triangles.push_back({2 * a, 2 * b + 1, 2 * b});
    }
    return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    IncisionMesh mesh = box();
    CutSurface strip;
    for (int stroke = 0; stroke < 2 && next_strip(data, size, strip); ++stroke) {
        const IncisionMesh before = mesh;
        IncisionResult result;
        try {
            result = open_along(mesh, strip, 0.02);
        } catch (const std::exception& e) {
            fuzz::broken(std::string("open_along threw: ") + e.what());
        }
        if (!result.opened) {
            if (mesh.triangles != before.triangles || mesh.rest != before.rest) fuzz::broken("a refused stroke changed the mesh");
            continue;
        }
        std::string why;
        if (!closed_manifold(mesh.triangles, &why)) fuzz::broken("the opened mesh is not closed: " + why);
        for (const auto& p : mesh.rest)
            if (!p.allFinite()) fuzz::broken("a vertex of the opened mesh is not finite");
        if (mesh.cap.size() != mesh.triangles.size() || mesh.normals.size() != mesh.rest.size()) fuzz::broken("the mesh's arrays disagree");
    }
    return 0;
}
