# stereoloc — set-up contract: `make demo` and `make test` on a fresh Debian 12 machine as root.
BUILD      ?= build
ASAN_BUILD ?= build-asan
JOBS       ?= $(shell nproc)
DEMO_OUT   ?= out/demo

# Debian 12 packages the build needs; installed only when missing (libopencv-imgcodecs-dev for
# the tests alone: OpenCV's decoder is the reference the image reader is compared with).
PACKAGES := cmake ninja-build g++ pkg-config \
            libceres-dev libeigen3-dev libsuitesparse-dev \
            libopencv-core-dev libopencv-imgproc-dev libopencv-calib3d-dev libopencv-imgcodecs-dev \
            libgtest-dev libbenchmark-dev libcli11-dev zlib1g-dev libjpeg-dev libpng-dev

SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: all deps configure build demo test test-asan test-valgrind bench clean

all: build

deps:
	@missing=""; \
	for p in $(PACKAGES); do \
	  dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q '^install ok installed$$' || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing missing packages:$$missing"; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi

$(BUILD)/build.ninja: | deps
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Release

configure: deps $(BUILD)/build.ninja

build: configure
	cmake --build $(BUILD) -j $(JOBS)

demo: build
	$(BUILD)/bin/stereoloc study --frontend images --trials 40 --out $(DEMO_OUT) --force

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS)

test-asan: deps
	cmake -S . -B $(ASAN_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSTEREOLOC_SANITIZE=ON -DSTEREOLOC_PCH=OFF \
	  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG"
	cmake --build $(ASAN_BUILD) -j $(JOBS)
	cd $(ASAN_BUILD) && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
	  ctest --output-on-failure -j $(JOBS)

# valgrind memcheck on the estimators end to end (simulated images -> frontend -> estimator):
# catches reads of uninitialised memory, which ASan does not (a batch-smoother bug of that kind
# once made a result depend on the heap). A few minutes; not part of `make test`.
VG_DIR := $(BUILD)/valgrind
VALGRIND := valgrind --error-exitcode=9 --track-origins=yes --leak-check=full --errors-for-leak-kinds=definite -q \
  --suppressions=tests/valgrind.supp
test-valgrind: build
	@dpkg-query -W -f='$${Status}\n' valgrind 2>/dev/null | grep -q '^install ok installed$$' || \
	  { $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends valgrind >/dev/null; }
	$(BUILD)/bin/stereoloc simulate --scenario circle --steps 40 --images --obstacles 1 --out $(VG_DIR)/data --force >/dev/null
	$(VALGRIND) $(BUILD)/bin/stereoloc detect --left $(VG_DIR)/data/images/left_000010.png \
	  --right $(VG_DIR)/data/images/right_000010.png --json >/dev/null
	@for m in fix1 fix2 ekf pf window batch; do \
	  echo "valgrind: localize --method $$m --frontend images"; \
	  $(VALGRIND) $(BUILD)/bin/stereoloc localize $(VG_DIR)/data --method $$m --frontend images \
	    $$([ $$m = pf ] && echo --particles 300) --out $(VG_DIR)/$$m.csv >/dev/null || exit 1; \
	done
	@for m in window batch ekf; do \
	  echo "valgrind: localize --method $$m --frontend images --calibrate odometry,stereo --noise-model"; \
	  $(VALGRIND) $(BUILD)/bin/stereoloc localize $(VG_DIR)/data --method $$m --frontend images \
	    --calibrate odometry,stereo --noise-model data/noise_realistic.yaml \
	    --calibration-out $(VG_DIR)/$$m-rig.yaml --out $(VG_DIR)/$$m-calib.csv >/dev/null || exit 1; \
	done
	@echo "valgrind: stream --method ekf --frontend images --calibrate odometry,stereo --noise-model"
	@$(VALGRIND) $(BUILD)/bin/stereoloc stream --from $(VG_DIR)/data --method ekf --frontend images \
	  --calibrate odometry,stereo --noise-model data/noise_realistic.yaml >/dev/null
	@echo "valgrind: localize --method ekf --frontend images --consider odometry,stereo --noise-model"
	@$(VALGRIND) $(BUILD)/bin/stereoloc localize $(VG_DIR)/data --method ekf --frontend images \
	  --consider odometry,stereo --noise-model data/noise_realistic.yaml --out $(VG_DIR)/ekf-consider.csv >/dev/null
	@echo "valgrind: the filters going back for late observations (Localizer replay)"
	@$(VALGRIND) $(BUILD)/bin/test_pipeline \
	  --gtest_filter='Localizer.TheFiltersReplayTheirStepsForLateObservations' >/dev/null
	@echo "valgrind: a range sensor's calibration in the batch and the window; errors that repeat over sightings"
	@$(VALGRIND) $(BUILD)/bin/test_solvers \
	  --gtest_filter='RangeCalibration.WindowAsLongAsTheDataIsTheBatch:RangeCalibration.TheGateSeesTheSightingsThroughTheCalibration' >/dev/null
	@$(VALGRIND) $(BUILD)/bin/test_core --gtest_filter='CorrelatedErrors.*:ErrorCorrelation.*:ErrorCorrelationFit.*' >/dev/null
	@echo "valgrind: the odometry's delay: re-timing, the stream's re-timer, the profile"
	@$(VALGRIND) $(BUILD)/bin/test_core --gtest_filter='OdometryDelay.*' >/dev/null
	@$(VALGRIND) $(BUILD)/bin/test_pipeline \
	  --gtest_filter='Localizer.WheelScalesAndTheOdometryDelayApplyToTheIncomingIncrements' >/dev/null
	@$(VALGRIND) $(BUILD)/bin/test_solvers \
	  --gtest_filter='OdometryDelayProfile.AQuadraticCostGivesItsVertexAndCurvature:OdometryDelayProfile.NoInteriorMinimumOrAFlatCostIsAnErrorAndFarCostsDoNotEnter' >/dev/null
	@echo "valgrind: localize --method ekf --frontend images --rig (the calibrated rig)"
	@$(VALGRIND) $(BUILD)/bin/stereoloc localize $(VG_DIR)/data --method ekf --frontend images \
	  --rig $(VG_DIR)/batch-rig.yaml --out $(VG_DIR)/ekf-rig.csv >/dev/null
	@echo "valgrind: calibrate from checkerboard pairs (simulate --calibration-views), the joint problem's Jacobian"
	$(BUILD)/bin/stereoloc simulate --scenario spin --steps 2 --profile realistic --calibration-views 6 \
	  --out $(VG_DIR)/cal --force >/dev/null
	@$(VALGRIND) $(BUILD)/bin/stereoloc calibrate $(VG_DIR)/cal/calibration --out $(VG_DIR)/cal/stereo.yml \
	  --rig-out $(VG_DIR)/cal/rig.yaml >/dev/null
	@$(VALGRIND) $(BUILD)/bin/test_calib --gtest_filter='StereoTargetProblem.*' >/dev/null
	@echo "valgrind: calibrate on real photographs through OpenCV's image list, with overlays; finding pairs on disk"
	@$(VALGRIND) $(BUILD)/bin/stereoloc calibrate data/real/checkerboard/stereo_calib.xml --square-mm 1 \
	  --out $(VG_DIR)/cal/real.yml --overlay $(VG_DIR)/cal/overlay >/dev/null
	@$(VALGRIND) $(BUILD)/bin/test_calib --gtest_filter='TargetPairs.*:RectifiedView.*' >/dev/null
	@echo "valgrind: cameras that do not expose together (the rig's offset; estimating it in the batch; the stream)"
	@cp $(VG_DIR)/data/rig.yaml $(VG_DIR)/timed.yaml && echo "exposure_offset_s: 0.004" >> $(VG_DIR)/timed.yaml
	@{ cat data/noise_realistic.yaml; echo "exposure_offset_sigma_s: 0.003"; } > $(VG_DIR)/noise_exposure.yaml
	@$(VALGRIND) $(BUILD)/bin/stereoloc localize $(VG_DIR)/data --method batch --frontend images --rig $(VG_DIR)/timed.yaml \
	  --calibrate odometry,stereo --noise-model $(VG_DIR)/noise_exposure.yaml --out $(VG_DIR)/timed.csv >/dev/null
	@$(VALGRIND) $(BUILD)/bin/stereoloc stream --from $(VG_DIR)/data --method ekf --frontend images \
	  --rig $(VG_DIR)/timed.yaml --calibrate odometry,stereo --noise-model $(VG_DIR)/noise_exposure.yaml >/dev/null
	@$(VALGRIND) $(BUILD)/bin/test_core --gtest_filter='BodyRate.*:BodyRateTracker.*:ExposureOffset.*' >/dev/null
	@echo "valgrind: no errors"

bench: build
	@for b in $(BUILD)/bin/bench_*; do echo "== $$b"; $$b; done

clean:
	rm -rf $(BUILD) $(ASAN_BUILD)
