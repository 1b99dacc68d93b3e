#pragma once
// The effect classes of the catalogue (effects.h), grouped by where the error arises: the tool
// (effects_tool.cc), the machine's axes and temperature (effects_machine.cc), the set-up
// (effects_setup.cc) and the probe (effects_probe.cc). Only effects.cc's registry calls these.

#include "simulation/effects.h"

namespace formloop::sim {

const Effect* ScallopEffect();
const Effect* ToolRadiusEffect();
const Effect* ToolWearEffect();
const Effect* ToolDeflectionEffect();
const Effect* ThermalDriftZEffect();
const Effect* AxisScaleEffect(int axis);   // 0 x, 1 y, 2 z
const Effect* SquarenessEffect(int pair);  // 0 xy, 1 yz, 2 zx
const Effect* BacklashEffect(int axis);    // 0 x, 1 y
const Effect* SetupOffsetEffect();
const Effect* SetupRotationEffect();
const Effect* ProbeRadiusEffect();
const Effect* ProbeLobingEffect();
const Effect* NoiseEffect();

}  // namespace formloop::sim
