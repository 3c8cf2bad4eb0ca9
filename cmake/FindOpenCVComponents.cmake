# Finds the OpenCV component libraries that stereoloc uses from Debian's per-component -dev
# packages (libopencv-core-dev, ...), which ship headers and libraries but no OpenCVConfig.cmake
# (that comes only with the libopencv-dev meta package and all of OpenCV).
# Defines imported targets OpenCV::<component> for each of OpenCVComponents_FIND_COMPONENTS.
find_path(OpenCVComponents_INCLUDE_DIR opencv2/core.hpp PATH_SUFFIXES opencv4)
set(OpenCVComponents_FOUND TRUE)
foreach(_c ${OpenCVComponents_FIND_COMPONENTS})
  find_library(OpenCVComponents_${_c}_LIBRARY NAMES opencv_${_c})
  if(OpenCVComponents_INCLUDE_DIR AND OpenCVComponents_${_c}_LIBRARY)
    if(NOT TARGET OpenCV::${_c})
      add_library(OpenCV::${_c} UNKNOWN IMPORTED)
      set_target_properties(OpenCV::${_c} PROPERTIES
        IMPORTED_LOCATION "${OpenCVComponents_${_c}_LIBRARY}"
        INTERFACE_INCLUDE_DIRECTORIES "${OpenCVComponents_INCLUDE_DIR}")
    endif()
  else()
    set(OpenCVComponents_FOUND FALSE)
    if(OpenCVComponents_FIND_REQUIRED)
      message(FATAL_ERROR "OpenCV component '${_c}' not found: install libopencv-${_c}-dev")
    endif()
  endif()
endforeach()
