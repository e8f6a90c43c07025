"""The HTML report's style sheet: one page that reads on a phone, a tablet and a desktop —
every table in its own scrolling box, no break inside a number or a word, the plots full width
on narrow screens (checked in headless Chromium by tests/test_report_browser.py)."""

CSS = """
* { box-sizing: border-box; }
body { margin: 0; padding: 16px; background: #f4f5f7; color: #1d2125;
       font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif; }
main { width: 1100px; max-width: 100%; margin: 0 auto; }
section, header { background: #fff; border-radius: 8px; padding: 18px 22px; margin: 0 0 16px;
                  box-shadow: 0 1px 2px rgba(0,0,0,.08); }
h1, h2, h3 { margin: 0 0 10px; line-height: 1.2; }
h2 { font-size: 22px; } h3 { font-size: 17px; margin-top: 18px; }
.verdict { border-left: 14px solid; }
.verdict .label { text-transform: uppercase; letter-spacing: .08em; font-size: 13px; color: #555; }
.verdict .why { font-size: 18px; margin: 0 0 10px; }
#statistics { margin: 10px 0 0; }
.v-none { border-color: #2e7d32; }
.v-effect { border-color: #e69500; }
.v-unexplained { border-color: #c62828; }
.path { display: flex; flex-wrap: wrap; gap: 6px; align-items: center; padding: 0; margin: 0;
        list-style: none; font-size: 14px; }
.chip { padding: 3px 10px; border-radius: 14px; color: #fff; white-space: nowrap; }
.chip.v-none { background: #2e7d32; } .chip.v-effect { background: #e69500; }
.chip.v-unexplained { background: #c62828; }
.arrow { color: #888; }
nav ol { margin: 0; padding-left: 20px; columns: 2; }
table { width: 100%; border-collapse: collapse; table-layout: auto; font-size: 14px; margin: 6px 0 4px; }
th, td { padding: 4px 8px; border-bottom: 1px solid #e3e5e8; text-align: left; vertical-align: top;
         overflow-wrap: normal; word-break: normal; hyphens: none; }
th { background: #f0f2f5; font-weight: 600; overflow-wrap: normal; word-break: normal; }
dl.glossary dt { font-weight: 600; margin-top: 6px; } dl.glossary dd { margin: 0 0 0 16px; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
/* A table wider than its box scrolls inside its own box; the page never does. */
.tbl { max-width: 100%; overflow-x: auto; margin: 6px 0 4px; }
.tbl table { margin: 0; }
table.narrow { width: auto; min-width: 50%; }
th.bars { min-width: 9em; }
th.num { white-space: normal; }  /* a header may wrap between its words, never inside one */
.hash .h-full { position: absolute; width: 1px; height: 1px; overflow: hidden;
                clip: rect(0 0 0 0); white-space: nowrap; }
.verdict .lead { font-size: 21px; font-weight: 600; margin: 0 0 8px; }
.verdict .badge { display: inline-block; padding: 1px 10px; border-radius: 12px; color: #fff;
                  font-weight: 700; text-transform: none; letter-spacing: 0; }
.v-none .badge { background: #2e7d32; } .v-effect .badge { background: #b86e00; }
.v-unexplained .badge { background: #c62828; }
.nowrap { white-space: nowrap; overflow-wrap: normal; }
/* Tables side by side on a grid with the page's gap; one column when they do not fit. */
.pair { display: grid; grid-template-columns: repeat(auto-fit, minmax(min(420px, 100%), 1fr)); gap: 16px; }
.pair > div { min-width: 0; }
.pair .tbl { margin: 0; }
tr.win td { background: #fff4dc; font-weight: 600; }
tr.off td { color: #888; }
tr.bad td { color: #b71c1c; }
tr.note td { color: #b71c1c; font-size: 13px; border-bottom: 1px solid #e3e5e8; padding-top: 0; }
.bar { position: relative; height: 14px; background: #eef0f3; border-radius: 3px; margin-top: 3px; }
.bar span { position: absolute; left: 0; top: 0; bottom: 0; border-radius: 3px; }
.bar i { position: absolute; top: -2px; bottom: -2px; width: 2px; background: #333; }
.ok { color: #2e7d32; } .warn { color: #b86e00; } .err { color: #c62828; }
.kv { display: grid; grid-template-columns: 220px 1fr; gap: 2px 12px; margin: 0; }
.kv dt { color: #555; } .kv dd { margin: 0; overflow-wrap: anywhere; }
code { font: 13px/1.3 ui-monospace, "DejaVu Sans Mono", monospace; }
figure { margin: 14px 0 0; }
figure img { display: block; width: 100%; height: auto; border: 1px solid #e3e5e8; }
figcaption { font-size: 14px; color: #444; margin: 4px 0 0; }
figure.skipped { padding: 10px 12px; background: #f4f5f7; color: #666; border-radius: 4px; }
.change { background: #fbfcfe; }
.change .line { font-size: 20px; font-weight: 600; margin: 0 0 4px; }
ul.notes { margin: 4px 0; padding-left: 20px; font-size: 14px; }
details summary { cursor: pointer; color: #345; margin-top: 8px; }
.muted { color: #666; font-size: 14px; }
/* Last, so that it overrides the rules above on a phone (.kv's columns were not). */
@media (max-width: 640px) {
  /* A phone: each row a card, each value beside its column's label (data-label). */
  table.cards, .cards tbody, .cards tr { display: block; width: 100%; }
  .cards colgroup, .cards tr.head { display: none; }
  .cards tr { border-bottom: 1px solid #e3e5e8; padding: 4px 0; }
  .cards td { display: block; border: 0; padding: 1px 4px; }
  .cards td[data-label] { display: grid; grid-template-columns: minmax(0, 42%) minmax(0, 1fr);
                          gap: 0 10px; }
  .cards td[data-label]::before { content: attr(data-label); color: #555; font-size: 13px;
                                  text-align: left; white-space: normal; }
  .cards td[data-label]:has(> .v:empty) { display: none; }
  .cards td:first-child .v { font-weight: 600; }
  .cards td.num { white-space: normal; }
  body { padding: 6px; font-size: 15px; }
  section, header { padding: 12px 10px; border-radius: 6px; }
  .verdict { border-left-width: 8px; }
  .verdict .lead { font-size: 18px; }
  .kv { grid-template-columns: 1fr; } .kv dd { margin-bottom: 6px; }
  nav ol { columns: 1; }
  figure { margin-left: -10px; margin-right: -10px; }
}
"""
