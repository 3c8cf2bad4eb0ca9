#include "src/renderer.h"

#include "src/dataset.h"
#include "src/error.h"
#include "src/simulator.h"

namespace stereoloc {

void RenderOptions::validate() const {}

void writeDatasetImages(const Dataset&, const SimulationTrace&, const RenderOptions&, uint64_t, const std::string&) {
  throw Error("simulate --images: the renderer is not available yet");
}

}  // namespace stereoloc
