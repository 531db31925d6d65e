# What a target links, all the way down: its own link libraries and, recursively, every target's
# interface link libraries (a static library's private dependencies are among them, as
# $<LINK_ONLY:...>, because whoever links it must link them too) and, for this project's own
# targets, their link libraries too (so a shared build, whose private dependencies stay private,
# is checked as strictly). Aliases are resolved to the targets they name; a name that is not a
# target (-lm, a path) is kept as it is written, and so is any other generator expression, whole:
# it matches no allowed name, so the check fails closed on what it cannot read.
#
# lftrack_link_closure(<target> <out-var>) sets <out-var> to the sorted list of names.
# lftrack_require_link_closure(<target> ALLOWED <regex>... [WHY <text>]) fails the configure when
# the closure holds a name that matches none of the regular expressions, saying which and through
# what it came. Call both after every target involved is defined (the top-level CMakeLists does, at
# its end).

function(_lftrack_link_name item out)
  # $<LINK_ONLY:x> -> x; other generator expressions are kept whole.
  if(item MATCHES "^\\$<LINK_ONLY:(.+)>$")
    set(item "${CMAKE_MATCH_1}")
  endif()
  if(TARGET "${item}")
    get_target_property(aliased "${item}" ALIASED_TARGET)
    if(aliased)
      set(item "${aliased}")
    endif()
  endif()
  set(${out} "${item}" PARENT_SCOPE)
endfunction()

function(lftrack_link_closure target out)
  set(seen "")
  get_target_property(direct ${target} LINK_LIBRARIES)
  if(direct STREQUAL "direct-NOTFOUND")
    set(direct "")
  endif()
  set(queue "")
  foreach(item IN LISTS direct)
    _lftrack_link_name("${item}" name)
    list(APPEND queue "${name}")
    set(via_${name} "${target}")
  endforeach()
  list(LENGTH queue left)  # not if(queue): a list ending in X-NOTFOUND reads as false
  while(left GREATER 0)
    list(POP_FRONT queue name)
    list(LENGTH queue left)
    if(name IN_LIST seen OR name STREQUAL "")
      continue()
    endif()
    list(APPEND seen "${name}")
    if(TARGET "${name}")
      get_target_property(deps "${name}" INTERFACE_LINK_LIBRARIES)
      if(deps STREQUAL "deps-NOTFOUND")
        set(deps "")
      endif()
      get_target_property(imported "${name}" IMPORTED)
      if(NOT imported)
        get_target_property(own "${name}" LINK_LIBRARIES)
        if(NOT own STREQUAL "own-NOTFOUND")
          list(APPEND deps ${own})
        endif()
      endif()
      list(LENGTH deps n_deps)
      if(n_deps GREATER 0)
        foreach(item IN LISTS deps)
          _lftrack_link_name("${item}" dep)
          if(NOT dep IN_LIST seen)
            list(APPEND queue "${dep}")
            list(LENGTH queue left)
            if(NOT DEFINED via_${dep})
              set(via_${dep} "${name}")
            endif()
          endif()
        endforeach()
      endif()
    endif()
  endwhile()
  list(SORT seen)
  # For the caller's messages: through which target each name came.
  foreach(name IN LISTS seen)
    set(LFTRACK_LINK_VIA_${name} "${via_${name}}" PARENT_SCOPE)
  endforeach()
  set(${out} "${seen}" PARENT_SCOPE)
endfunction()

function(lftrack_require_link_closure target)
  cmake_parse_arguments(ARG "" "WHY" "ALLOWED" ${ARGN})
  lftrack_link_closure(${target} closure)
  foreach(name IN LISTS closure)
    set(allowed FALSE)
    foreach(pattern IN LISTS ARG_ALLOWED)
      if(name MATCHES "${pattern}")
        set(allowed TRUE)
        break()
      endif()
    endforeach()
    if(NOT allowed)
      message(FATAL_ERROR "${target} links ${name} (through ${LFTRACK_LINK_VIA_${name}}), which it may not: "
                          "${ARG_WHY}\nWhat it links, all the way down: ${closure}")
    endif()
  endforeach()
endfunction()

# lftrack_forbid_link(<target> FORBIDDEN <regex>... [WHY <text>]) fails the configure when the
# target's closure holds a name that matches any of the regular expressions: a dependency that
# must never run the other way.
function(lftrack_forbid_link target)
  cmake_parse_arguments(ARG "" "WHY" "FORBIDDEN" ${ARGN})
  lftrack_link_closure(${target} closure)
  foreach(name IN LISTS closure)
    foreach(pattern IN LISTS ARG_FORBIDDEN)
      if(name MATCHES "${pattern}")
        message(FATAL_ERROR "${target} links ${name} (through ${LFTRACK_LINK_VIA_${name}}), which it may not: "
                            "${ARG_WHY}")
      endif()
    endforeach()
  endforeach()
endfunction()
