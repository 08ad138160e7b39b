#include "libmodel/progress.h"

namespace heartsim {

namespace {
class NullProgress final : public Progress {
public:
    void begin(std::string_view, std::uint64_t) override {}
    void update(std::uint64_t) override {}
    void end() override {}
};
}  // namespace

Progress& null_progress() {
    static NullProgress instance;
    return instance;
}

}  // namespace heartsim
