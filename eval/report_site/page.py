"""The HTML skeleton of every report page: inline CSS and JavaScript, no network, no CDN.

Behaviour (plain JavaScript, works from file://): a click on a table header sorts its rows
by that column (numbers by value, "--" last, a second click reverses); view buttons show
one view of a scene at a time.
"""
from __future__ import annotations

from html import escape
from urllib.parse import quote

CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:1.5em;color:#222;max-width:1600px}
h1{font-size:1.5em} h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ccc}
table.metrics{border-collapse:collapse;margin:.5em 0;font-size:13px}
table.metrics th,table.metrics td{border:1px solid #ccc;padding:2px 6px;text-align:right}
table.metrics th{background:#f2f2f2;cursor:pointer;user-select:none}
table.metrics th.sorted-asc::after{content:" \\25B2"} table.metrics th.sorted-desc::after{content:" \\25BC"}
table.metrics td:first-child,table.metrics th:first-child{text-align:left}
td.best{background:#ffebee;font-weight:bold} td.second{background:#fff9c4;text-decoration:underline}
.footer{font-size:12px;color:#555} .footer li{margin:0}
.grid{border-collapse:collapse} .grid th{font-weight:normal;font-size:12px;padding:2px}
.grid td{vertical-align:top;padding:3px}
.tile{display:inline-block;text-align:center;font-size:11px;margin:0}
.tile img{display:block;width:128px;height:128px;image-rendering:auto;background:#000}
.pair{display:flex;gap:2px}
.missing{width:128px;height:128px;box-sizing:border-box;border:1px solid #999;display:flex;
 align-items:center;justify-content:center;color:#a00;font-size:11px;padding:4px;background:
 linear-gradient(to top right,transparent calc(50% - 1px),#bbb,transparent calc(50% + 1px)),
 linear-gradient(to bottom right,transparent calc(50% - 1px),#bbb,transparent calc(50% + 1px))}
.env img{width:128px;height:64px;display:block}
.cbar{display:inline-block;width:200px;height:12px;vertical-align:middle;border:1px solid #999}
.views button{margin:0 2px} .views button.on{background:#333;color:#fff}
.view{display:none} .view.on{display:block}
.problems li{color:#a00}
.anim img{width:192px;height:192px}
.glb img{width:512px;height:128px;background:#fff}
"""

JS = """
function cellValue(td){const v=td.getAttribute('data-v');
  if(v===null||v===''){return null;} const x=parseFloat(v); return isNaN(x)?v:x;}
function sortTable(th){
  const table=th.closest('table'); const idx=Array.from(th.parentNode.children).indexOf(th);
  const asc=!th.classList.contains('sorted-asc');
  table.querySelectorAll('th').forEach(h=>h.classList.remove('sorted-asc','sorted-desc'));
  th.classList.add(asc?'sorted-asc':'sorted-desc');
  const body=table.tBodies[0]; const rows=Array.from(body.rows);
  rows.sort((a,b)=>{const x=cellValue(a.cells[idx]),y=cellValue(b.cells[idx]);
    if(x===null&&y===null)return 0; if(x===null)return 1; if(y===null)return -1;
    if(typeof x==='number'&&typeof y==='number')return asc?x-y:y-x;
    return asc?String(x).localeCompare(String(y)):String(y).localeCompare(String(x));});
  rows.forEach(r=>body.appendChild(r));}
function showView(id){
  document.querySelectorAll('.view').forEach(v=>v.classList.toggle('on',v.dataset.view===id));
  document.querySelectorAll('.views button').forEach(b=>b.classList.toggle('on',b.dataset.view===id));}
document.addEventListener('DOMContentLoaded',()=>{
  document.querySelectorAll('table.metrics th').forEach(th=>th.addEventListener('click',()=>sortTable(th)));
  document.querySelectorAll('.views button').forEach(b=>b.addEventListener('click',()=>showView(b.dataset.view)));
  const first=document.querySelector('.views button'); if(first){showView(first.dataset.view);}
});
"""


def page(title: str, body: str) -> str:
    """A complete HTML document around `body` (already escaped HTML)."""
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{escape(title)}</title><link rel=\"icon\" href=\"data:,\">"
            f"<style>{CSS}</style><script>{JS}</script></head>\n"
            f"<body>\n{body}\n</body></html>\n")


def url(rel_path: str) -> str:
    """A relative file path as an attribute value: percent-encoded (scene names may hold any
    character) and HTML-escaped."""
    return escape(quote(rel_path))


def tile(src: str | None, caption: str, *, note: str = "", alt: str = "") -> str:
    """An image with a caption, or a crossed "missing" box stating `note`."""
    inner = (f"<img src=\"{url(src)}\" alt=\"{escape(alt)}\">" if src
             else f"<div class=\"missing\">{escape(note or 'missing')}</div>")
    return f"<figure class=\"tile\">{inner}<figcaption>{caption}</figcaption></figure>"
