SUMMARY = "ALACS CAN protocol: DBC for any node id, cantools codec helpers"
DESCRIPTION = "The Python side of the ALACS CAN protocol (can_protocol/python): the DBC, \
               encode/decode helpers and result assembly used by the alacs CLI and robot software."
HOMEPAGE = "https://alacs.invalid/"
BUGTRACKER = "https://alacs.invalid/issues"
SECTION = "devel/python"
LICENSE = "Apache-2.0"
# The repository has no LICENSE file yet: the common Apache-2.0 text stands in.
# nooelint: oelint.var.licenseremotefile
LIC_FILES_CHKSUM = "file://${COMMON_LICENSE_DIR}/Apache-2.0;md5=89aea4e17d99a7cacdbeed46a0096b10"
CVE_PRODUCT = "alacs-can"

PV = "1.0.0+git"

require recipes-alacs/alacs-source.inc

SRC_URI = "${ALACS_GIT_URI};branch=${ALACS_GIT_BRANCH}"
# Built from the commit the layer belongs to (see alacsd_git.bb).
# nooelint: oelint.vars.autorev
SRCREV = "${AUTOREV}"

S = "${WORKDIR}/git/can_protocol/python"

inherit python_setuptools_build_meta

RDEPENDS:${PN} = "python3-can python3-cantools"

BBCLASSEXTEND = "native nativesdk"
