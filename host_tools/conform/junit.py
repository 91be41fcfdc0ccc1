"""The suite's results as JUnit XML, the report CI systems read (one testcase per check, its class the section of
docs/protocol.md it tests; a failed SHOULD is a failure too, named so in its message)."""
from __future__ import annotations

import xml.etree.ElementTree as ET

from host_tools.outputs import Kind, begins
from host_tools.conform.runner import FAIL, SKIP, Result

JUNIT = Kind("a JUnit XML report (it begins `<?xml` or `<testsuites`)", begins(b"<?xml", b"<testsuites"),
             (".xml",))


def junit_xml(results: list[Result], target: str, elapsed_s: float) -> str:
    failures = sum(r.status == FAIL for r in results)
    skipped = sum(r.status == SKIP for r in results)
    suites = ET.Element("testsuites", name="aspod conform", tests=str(len(results)), failures=str(failures),
                        errors="0", skipped=str(skipped), time=f"{elapsed_s:.3f}")
    suite = ET.SubElement(suites, "testsuite", name="aspod conform", tests=str(len(results)),
                          failures=str(failures), errors="0", skipped=str(skipped), time=f"{elapsed_s:.3f}")
    properties = ET.SubElement(suite, "properties")
    ET.SubElement(properties, "property", name="target", value=target)
    for r in results:
        case = ET.SubElement(suite, "testcase", classname=f"protocol.md.{r.check.section}", name=r.check.name,
                             time=f"{r.duration_s:.3f}")
        if r.status == FAIL:
            failure = ET.SubElement(case, "failure", type=r.check.level,
                                    message=f"{r.check.level} {r.check.cites}: expected {r.expected}")
            failure.text = f"{r.check.what}\nexpected: {r.expected}\nsaw: {r.seen}\n"
        elif r.status == SKIP:
            ET.SubElement(case, "skipped", message=r.detail)
        else:
            ET.SubElement(case, "system-out").text = r.detail
    ET.indent(suites)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(suites, encoding="unicode") + "\n"
